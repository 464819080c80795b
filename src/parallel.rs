//! Small scoped-thread helpers. Work is split so results never depend on the thread count:
//! each item or chunk is computed the same way whichever thread takes it.

use std::sync::Mutex;

/// Runs `f` on every item, on up to `threads` scoped threads pulling from a shared queue.
pub fn par_for_each<T: Send>(items: Vec<T>, threads: usize, f: impl Fn(T) + Sync) {
    if threads <= 1 || items.len() <= 1 {
        items.into_iter().for_each(f);
        return;
    }
    let queue = Mutex::new(items.into_iter());
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                loop {
                    let next = queue.lock().unwrap_or_else(|e| e.into_inner()).next();
                    match next {
                        Some(item) => f(item),
                        None => break,
                    }
                }
            });
        }
    });
}

/// Calls `f(first_index, chunk)` on consecutive chunks of `data` (about `4·threads` of them),
/// in parallel.
pub fn par_chunks_mut<T: Send>(data: &mut [T], threads: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    let len = data.len();
    if len == 0 {
        return;
    }
    let chunk = len.div_ceil(threads.max(1) * 4).max(4096);
    let items: Vec<(usize, &mut [T])> = data.chunks_mut(chunk).enumerate().map(|(i, c)| (i * chunk, c)).collect();
    par_for_each(items, threads, |(start, c)| f(start, c));
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
}
