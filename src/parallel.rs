//! The one parallel work queue of the crate. Work is split so results never depend on the
//! thread count: each item is computed the same way whichever thread takes it, and results
//! come back in item order.

use std::sync::atomic::{AtomicUsize, Ordering};

/// Worker threads to use when the caller did not say: every core.
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `f` applied to every item on up to `threads` scoped threads pulling items from a shared
/// counter (dynamic load balancing); the results in item order. A worker's panic is a bug
/// and is passed on to the caller with its original payload, never swallowed (a missing
/// result would be a silently missing sample or texel).
pub fn par_map<T: Send, R: Send>(items: Vec<T>, threads: usize, f: impl Fn(T) -> R + Sync) -> Vec<R> {
    let n = items.len();
    let threads = threads.min(n);
    if threads <= 1 {
        return items.into_iter().map(f).collect();
    }
    // Each slot is taken by exactly one worker (the counter hands out each index once).
    let slots: Vec<std::sync::Mutex<Option<T>>> = items.into_iter().map(|t| std::sync::Mutex::new(Some(t))).collect();
    let next = AtomicUsize::new(0);
    let worker = || {
        let mut done = Vec::new();
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            if i >= n {
                return done;
            }
            let item = slots[i].lock().unwrap_or_else(|e| e.into_inner()).take();
            if let Some(item) = item {
                done.push((i, f(item)));
            }
        }
    };
    let parts: Vec<Vec<(usize, R)>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(worker)).collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
    });
    let mut out: Vec<Option<R>> = (0..n).map(|_| None).collect();
    for (i, r) in parts.into_iter().flatten() {
        out[i] = Some(r);
    }
    out.into_iter().flatten().collect()
}

/// Returns the heap memory freed so far to the system (glibc keeps what a thread frees in
/// that thread's arena, for its next allocations; after a parallel phase whose scratch was
/// freed on worker threads, nothing else may ask for it). Nothing elsewhere.
pub fn give_back_free_heap() {
    #[cfg(all(unix, target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free heap memory to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Runs `f` on every item in parallel (see [`par_map`]).
pub fn par_for_each<T: Send>(items: Vec<T>, threads: usize, f: impl Fn(T) + Sync) {
    par_map(items, threads, f);
}

/// Calls `f(first_index, chunk)` on consecutive chunks of `data` (about `4·threads` of them,
/// at least 4096 elements each), in parallel.
pub fn par_chunks_mut<T: Send>(data: &mut [T], threads: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    if data.is_empty() {
        return;
    }
    let chunk = data.len().div_ceil(threads.max(1) * 4).max(4096);
    let items: Vec<(usize, &mut [T])> = data.chunks_mut(chunk).enumerate().map(|(i, c)| (i * chunk, c)).collect();
    par_for_each(items, threads, |(start, c)| f(start, c));
}

/// `f(i)` for every `i < n`, computed in parallel in runs of `chunk` consecutive indices, in
/// index order. `done(k)` is called from the workers after each run with the number of
/// indices finished so far (monotonic per call, not necessarily in order across threads).
pub fn par_map_indices<R: Send>(
    n: usize,
    chunk: usize,
    threads: usize,
    f: impl Fn(usize) -> R + Sync,
    done: &(dyn Fn(usize) + Sync),
) -> Vec<R> {
    let chunk = chunk.max(1);
    let finished = AtomicUsize::new(0);
    let runs: Vec<std::ops::Range<usize>> = (0..n).step_by(chunk).map(|s| s..(s + chunk).min(n)).collect();
    par_map(runs, threads, |run| {
        let len = run.len();
        let values: Vec<R> = run.map(&f).collect();
        done(finished.fetch_add(len, Ordering::Relaxed) + len);
        values
    })
    .into_iter()
    .flatten()
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_cover_everything_once() {
        let mut v = vec![0u32; 100_000];
        par_chunks_mut(&mut v, 3, |start, c| {
            for (i, x) in c.iter_mut().enumerate() {
                *x += (start + i) as u32;
            }
        });
        assert!(v.iter().enumerate().all(|(i, &x)| x == i as u32));
    }

    #[test]
    fn map_keeps_item_order_whatever_the_threads() {
        for threads in [1, 2, 7] {
            let out = par_map((0..1000u64).collect(), threads, |i| i * i);
            assert_eq!(out, (0..1000u64).map(|i| i * i).collect::<Vec<_>>());
            let idx = par_map_indices(1001, 64, threads, |i| i as u64 + 1, &|_| {});
            assert_eq!(idx, (1..=1001u64).collect::<Vec<_>>());
        }
    }

    #[test]
    fn a_worker_panic_reaches_the_caller_with_its_message() {
        let r = std::panic::catch_unwind(|| {
            par_map((0..64).collect(), 2, |i: i32| if i == 40 { panic!("item forty") } else { i })
        });
        let payload = r.expect_err("the panic must propagate");
        assert_eq!(payload.downcast_ref::<&str>().copied(), Some("item forty"));
    }
}
