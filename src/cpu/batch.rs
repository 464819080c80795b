//! One lane of a batch (its share of the directions, see [`super`]) on the threads given to
//! it, into the lane's sums.
//!
//! The lane is a sequence of units: for each direction in turn, its tiles in plan order,
//! then its light bundles (see [`super::direction`]). Every thread takes the next unit
//! (planning a direction when it comes to one not planned yet, while the others finish the
//! last one's units), so the threads work side by side within a direction and across
//! directions. Hits reach the sums **in unit order**, whatever the threads do: the thread on
//! the unit due next adds its hits straight to the sums; one ahead of it keeps them as
//! records, added when its turn comes. The sums are therefore those of one thread tracing
//! the lane in order, bit for bit, whatever the thread count, and no thread holds sums of
//! its own (16 B a texel each, 28 B with a light pass). The records waiting are bounded
//! ([`WAITING_HITS_PER_THREAD`]): a thread that finds that many waiting takes no unit ahead
//! of the one due until they drain.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

use super::direction::{BundleHits, DirectionPlan, LightHits, PassContext, Worker, plan_direction, trace_unit};
use super::prefetch::for_each_ahead;
use crate::bundle::DirectionJob;
use crate::bundle::estimator::{HitSink, TexelLayout};
use crate::bundle::progressive::BatchSums;
use crate::bundle::target::Cancelled;
use crate::scene::Rgb;

/// Hits a record chunk holds (20 B each: 640 KiB).
const CHUNK_HITS: usize = 32 * 1024;

/// Hits that may wait for their turn, per thread beyond the first, in units of the node
/// budget N: a tile holds about one hit per fragment, so N is about the largest tile, and
/// the other threads can run a largest tile's worth ahead of the unit due.
pub const WAITING_HITS_PER_THREAD: u64 = 1;

/// Empty chunks kept for the next units beyond those in use (the rest are freed).
const SPARE_CHUNKS: usize = 8;

/// Bytes the spare chunks hold at most.
pub const SPARE_RECORD_BYTES: u64 = (SPARE_CHUNKS * CHUNK_HITS * std::mem::size_of::<Hit>()) as u64;

/// One hit kept until its unit's turn.
#[derive(Clone, Copy)]
struct Hit {
    texel: u32,
    radiance: Rgb,
    weight: f32,
}

/// The hits of one unit, in the order they were made, in chunks from a shared pool.
#[derive(Default)]
struct Records {
    chunks: Vec<Vec<Hit>>,
    len: usize,
}

/// The hits of a unit traced ahead of its turn: records (chunks from `pool`) until the unit
/// is due, then its records and every later hit go straight to the sums. Whether it is due
/// is looked at when a chunk fills, so a unit keeps at most a chunk's worth after its turn
/// came.
struct RecordSink<'a> {
    records: Records,
    pool: &'a ChunkPool,
    unit: u64,
    due: &'a AtomicU64,
    sums: &'a SumsPtr,
    /// Where its kind's sums lie (see [`HitSink::sums_layout`]).
    layout: TexelLayout,
    /// A global-bundle tile (else a light bundle).
    tile: bool,
    /// Whether the unit's hits go straight to the sums now.
    straight: bool,
    /// Most records held at once.
    most: usize,
}

impl RecordSink<'_> {
    #[inline(always)]
    fn add(&mut self, texel: u32, radiance: Rgb, weight: f32) {
        // SAFETY: only once the unit is due (`straight`): see `Shared::sums`.
        let sums = unsafe { &mut *self.sums.0 };
        if self.tile {
            BundleHits(&mut sums.bundle).hit(texel, radiance, weight);
        } else {
            LightHits(&mut sums.light).hit(texel, radiance, weight);
        }
    }

    /// Adds the records to the sums and goes straight from now on; the unit must be due.
    fn go_straight(&mut self) {
        self.most = self.most.max(self.records.len);
        let records = std::mem::take(&mut self.records);
        for chunk in &records.chunks {
            for_each_ahead(chunk, self.layout, |h| h.texel, |h| self.add(h.texel, h.radiance, h.weight));
        }
        self.pool.give(records);
        self.straight = true;
    }

    /// A hit when the records' last chunk is full (or there is none): goes straight if the
    /// unit's turn has come, else opens a chunk.
    #[cold]
    #[inline(never)]
    fn hit_at_full_chunk(&mut self, texel: u32, radiance: Rgb, weight: f32) {
        if self.due.load(AtomicOrdering::Acquire) == self.unit {
            self.go_straight();
            return self.add(texel, radiance, weight);
        }
        let mut chunk = self.pool.take();
        chunk.push(Hit { texel, radiance, weight });
        self.records.chunks.push(chunk);
        self.records.len += 1;
    }
}

impl HitSink for RecordSink<'_> {
    fn sums_layout(&self) -> TexelLayout {
        self.layout
    }

    /// Inlined into the exchange (a call a hit was ~6% of a one-lane bake), with the common
    /// cases first: straight to the sums, or a record in a chunk with room.
    #[inline(always)]
    fn hit(&mut self, texel: u32, radiance: Rgb, weight: f32) {
        if self.straight {
            return self.add(texel, radiance, weight);
        }
        if let Some(chunk) = self.records.chunks.last_mut()
            && chunk.len() < CHUNK_HITS
        {
            chunk.push(Hit { texel, radiance, weight });
            self.records.len += 1;
            return;
        }
        self.hit_at_full_chunk(texel, radiance, weight);
    }
}

/// `unit` in one word, for [`Shared::due`].
fn packed(unit: UnitId) -> u64 {
    (unit.0 as u64) << 32 | unit.1 as u64
}

#[derive(Default)]
struct ChunkPool(Mutex<Vec<Vec<Hit>>>);

impl ChunkPool {
    fn take(&self) -> Vec<Hit> {
        lock(&self.0).pop().unwrap_or_else(|| Vec::with_capacity(CHUNK_HITS))
    }

    fn give(&self, records: Records) {
        let mut spare = lock(&self.0);
        for mut chunk in records.chunks {
            if spare.len() < SPARE_CHUNKS {
                chunk.clear();
                spare.push(chunk);
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A unit: direction `d`, unit `u` of its plan.
type UnitId = (usize, usize);

/// The sums, reached by one thread at a time: see [`Shared::sums`].
struct SumsPtr(*mut BatchSums);

// SAFETY: the pointer is dereferenced only under the turn protocol of `Shared::sums`, which
// gives one thread at a time access; `BatchSums` itself is `Send`.
unsafe impl Send for SumsPtr {}
unsafe impl Sync for SumsPtr {}

struct State {
    /// Each direction's plan, from its planning until its last unit is in the sums (its
    /// triangle bins alone may take megabytes).
    plans: Vec<Option<Arc<DirectionPlan>>>,
    /// Each direction's unit count, once planned.
    units: Vec<Option<usize>>,
    /// Whether a thread is planning the direction the next unit comes from.
    planning: bool,
    /// The next unit to hand out, and the next one due in the sums.
    next: UnitId,
    due: UnitId,
    /// Finished units ahead of the one due, and how many hits they hold.
    waiting: BTreeMap<UnitId, Records>,
    waiting_hits: u64,
    stopped: bool,
    cancelled: bool,
}

impl State {
    /// Moves `unit` past the ends of planned directions (a direction may have no units);
    /// stops at one not planned yet.
    fn settle(&self, mut unit: UnitId) -> UnitId {
        while let Some(&Some(units)) = self.units.get(unit.0) {
            if unit.1 < units {
                break;
            }
            unit = (unit.0 + 1, 0);
        }
        unit
    }

    /// Makes `unit` (settled) the one due, giving up the plans of the directions it passed.
    fn set_due(&mut self, unit: UnitId, shown: &AtomicU64) {
        let due = self.settle(unit);
        for plan in &mut self.plans[self.due.0.min(due.0)..due.0] {
            *plan = None;
        }
        self.due = due;
        shown.store(packed(due), AtomicOrdering::Release);
    }
}

struct Shared<'a> {
    ctx: &'a PassContext<'a>,
    batch: &'a [DirectionJob],
    state: Mutex<State>,
    turn: Condvar,
    pool: ChunkPool,
    /// The batch's sums. Only the thread whose unit is due reaches them: the one tracing
    /// it (which took it while it was due, and writes as it traces), or the one that
    /// finished the unit before it and adds it from the records; `due` moves on only when
    /// that thread is done with them.
    sums: SumsPtr,
    /// `State::due`, packed, for threads tracing ahead to see their turn come without the
    /// lock (written under it).
    due: AtomicU64,
    most_waiting: u64,
    /// [`HitSink::sums_layout`] of the global and the light-pass sums, taken before any
    /// thread starts (the sums are never reallocated while the batch runs).
    bundle_layout: TexelLayout,
    light_layout: TexelLayout,
}

/// What a thread does next.
enum Task {
    Plan(usize),
    /// A unit, and whether it was due when taken (its hits go straight to the sums).
    Trace(UnitId, Arc<DirectionPlan>, bool),
}

/// Traces `batch` into `sums` (zeroed, sized to the target) on one thread per `workers`
/// entry; per-unit statistics go to each worker's.
pub fn trace_batch(
    ctx: &PassContext,
    batch: &[DirectionJob],
    sums: &mut BatchSums,
    workers: &mut [Worker],
) -> Result<(), Cancelled> {
    let threads = workers.len().max(1) as u64;
    let (bundle_layout, light_layout) = (TexelLayout::of(&sums.bundle), TexelLayout::of(&sums.light));
    let shared = Shared {
        ctx,
        batch,
        state: Mutex::new(State {
            plans: (0..batch.len()).map(|_| None).collect(),
            units: vec![None; batch.len()],
            planning: false,
            next: (0, 0),
            due: (0, 0),
            waiting: BTreeMap::new(),
            waiting_hits: 0,
            stopped: false,
            cancelled: false,
        }),
        turn: Condvar::new(),
        pool: ChunkPool::default(),
        sums: SumsPtr(sums),
        due: AtomicU64::new(packed((0, 0))),
        most_waiting: ctx.waiting_hits.saturating_mul(threads - 1),
        bundle_layout,
        light_layout,
    };
    match workers {
        [] => {}
        [only] => work(&shared, only),
        _ => std::thread::scope(|s| {
            let handles: Vec<_> = workers.iter_mut().map(|w| s.spawn(|| work(&shared, w))).collect();
            // Joined here, so that a worker's panic reaches the caller with its own payload.
            for h in handles {
                h.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
            }
        }),
    }
    let state = shared.state.into_inner().unwrap_or_else(|e| e.into_inner());
    if state.cancelled { Err(Cancelled) } else { Ok(()) }
}

/// Stops the batch when its thread unwinds, so no other waits for a unit never coming.
struct StopOnPanic<'a, 'b>(&'a Shared<'b>);

impl Drop for StopOnPanic<'_, '_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            lock(&self.0.state).stopped = true;
            self.0.turn.notify_all();
        }
    }
}

/// One thread: takes tasks until none is left (or the batch stops).
fn work(shared: &Shared, w: &mut Worker) {
    let _stop = StopOnPanic(shared);
    while let Some(task) = next_task(shared) {
        let done = match task {
            Task::Plan(d) => plan(shared, d, w),
            Task::Trace(unit, plan, due) => trace(shared, unit, &plan, due, w),
        };
        if done.is_err() {
            let mut st = lock(&shared.state);
            st.stopped = true;
            st.cancelled = true;
            drop(st);
            shared.turn.notify_all();
            return;
        }
    }
}

fn next_task(shared: &Shared) -> Option<Task> {
    let mut st = lock(&shared.state);
    loop {
        if st.stopped {
            return None;
        }
        let next = st.settle(st.next);
        st.next = next;
        // Directions before the one due have given up their plans; `next` is never before it.
        match (*st.units.get(next.0)?, st.plans.get(next.0)?) {
            (None, _) if st.planning => {}
            (None, _) => {
                st.planning = true;
                return Some(Task::Plan(next.0));
            }
            (Some(_), None) => {
                unreachable!("a plan is given up only after its last unit is added, and `next` is never before it")
            }
            (Some(_), Some(plan)) => {
                let due = next == st.due;
                // Ahead of the unit due only while few hits wait; the unit due itself
                // always goes (it adds its hits as it makes them), so this never stalls.
                if due || st.waiting_hits < shared.most_waiting {
                    let plan = plan.clone();
                    st.next = (next.0, next.1 + 1);
                    return Some(Task::Trace(next, plan, due));
                }
            }
        }
        st = shared.turn.wait(st).unwrap_or_else(|e| e.into_inner());
    }
}

fn plan(shared: &Shared, d: usize, w: &mut Worker) -> Result<(), Cancelled> {
    let plan = plan_direction(shared.ctx, &shared.batch[d], w);
    let mut st = lock(&shared.state);
    st.planning = false;
    let result = plan.map(|p| {
        st.units[d] = Some(p.units());
        st.plans[d] = Some(Arc::new(p));
        // A direction with no units passes the turn on at once.
        let due = st.due;
        st.set_due(due, &shared.due);
        add_waiting(shared, &mut st);
    });
    drop(st);
    shared.turn.notify_all();
    result
}

fn trace(shared: &Shared, unit: UnitId, plan: &DirectionPlan, due: bool, w: &mut Worker) -> Result<(), Cancelled> {
    let (ctx, job) = (shared.ctx, &shared.batch[unit.0]);
    if due {
        // SAFETY: this unit was due when taken, so no other thread reaches the sums until
        // `due` moves past it, which only this thread does, below (see `Shared::sums`).
        let sums = unsafe { &mut *shared.sums.0 };
        let traced = {
            let (bundle, light) = (&mut BundleHits(&mut sums.bundle), &mut LightHits(&mut sums.light));
            trace_unit(ctx, job, plan, unit.1, w, bundle, light)
        };
        let mut st = lock(&shared.state);
        if traced.is_ok() {
            st.set_due((unit.0, unit.1 + 1), &shared.due);
            add_waiting(shared, &mut st);
        }
        drop(st);
        shared.turn.notify_all();
        return traced;
    }
    let tile = plan.is_tile(unit.1);
    let mut sink = RecordSink {
        records: Records::default(),
        pool: &shared.pool,
        unit: packed(unit),
        due: &shared.due,
        sums: &shared.sums,
        layout: if tile { shared.bundle_layout } else { shared.light_layout },
        tile,
        straight: false,
        most: 0,
    };
    let traced = if tile {
        trace_unit(ctx, job, plan, unit.1, w, &mut sink, &mut NoHits)
    } else {
        trace_unit(ctx, job, plan, unit.1, w, &mut NoHits, &mut sink)
    };
    let most = sink.most.max(sink.records.len) as u64;
    w.stats.peak_recorded_hits = w.stats.peak_recorded_hits.max(most);
    if traced.is_err() {
        shared.pool.give(sink.records);
        return traced;
    }
    let mut st = lock(&shared.state);
    if !sink.straight && st.due != unit {
        st.waiting_hits += sink.records.len as u64;
        st.waiting.insert(unit, sink.records);
    } else {
        if !sink.straight {
            // Its turn came after its last full chunk: the rest goes to the sums now.
            drop(st);
            sink.go_straight();
            st = lock(&shared.state);
        }
        st.set_due((unit.0, unit.1 + 1), &shared.due);
    }
    add_waiting(shared, &mut st);
    drop(st);
    shared.turn.notify_all();
    Ok(())
}

/// Adds the waiting units that are due, in order, moving `due` past each.
fn add_waiting(shared: &Shared, st: &mut State) {
    while let Some(records) = st.waiting.remove(&st.due) {
        let unit = st.due;
        let Some(Some(plan)) = st.plans.get(unit.0) else { break };
        // SAFETY: `due` is this unit, whose thread finished it into records: no thread
        // writes the sums straight, and the state's lock keeps other threads from adding.
        let sums = unsafe { &mut *shared.sums.0 };
        if plan.is_tile(unit.1) {
            add_records(&records, &mut BundleHits(&mut sums.bundle));
        } else {
            add_records(&records, &mut LightHits(&mut sums.light));
        }
        st.waiting_hits -= records.len as u64;
        shared.pool.give(records);
        st.set_due((unit.0, unit.1 + 1), &shared.due);
    }
}

fn add_records(records: &Records, sink: &mut impl HitSink) {
    let layout = sink.sums_layout();
    for chunk in &records.chunks {
        for_each_ahead(chunk, layout, |h| h.texel, |h| sink.hit(h.texel, h.radiance, h.weight));
    }
}

/// A sink for the hits a unit never makes (a tile makes no light-pass hits, and a light
/// bundle no global ones).
struct NoHits;

impl HitSink for NoHits {
    fn hit(&mut self, _texel: u32, _radiance: Rgb, _weight: f32) {
        debug_assert!(false, "a unit made a hit of the other kind");
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;

    use crate::atlas::texels::TexelMap;
    use crate::atlas::{Atlas, AtlasConfig};
    use crate::bundle::progressive::BatchSums;
    use crate::bundle::target::{BundleBackend, SourceRadiance, WholeLod};
    use crate::bundle::{BundleConfig, BundleScene, DirectionJob, JobSequence, Lanes};
    use crate::cpu::{CpuBundleBackend, CpuScene};
    use crate::scene::{Rgb, SceneGeometry};

    /// The Cornell box (its lamp gets the light pass) at `texel_budget` texels, `lanes` lanes.
    fn cornell(texel_budget: u64, lanes: u32) -> Arc<CpuScene> {
        let path = format!("{}/assets/cornell_box/cornellBox-2.79-Cycles-gltf.gltf", env!("CARGO_MANIFEST_DIR"));
        let scene = Arc::new(crate::scene::load_gltf(path.as_ref(), &Default::default()).expect("bundled scene"));
        let geom = SceneGeometry::new(&scene);
        let atlas =
            Atlas::build(&scene, &geom, &AtlasConfig { texel_budget, ..AtlasConfig::default() }).expect("atlas");
        let config = BundleConfig { lanes: Lanes::Fixed(lanes), ..BundleConfig::default() };
        let bundle = BundleScene::new(scene, Arc::new(geom), Arc::new(atlas), config);
        Arc::new(CpuScene::new(Arc::new(bundle)))
    }

    /// The threads of a lane add their hits in the order one thread would: a batch's sums
    /// (global and light pass) are the same bits on 1, 2 and 3 threads, with one lane and
    /// with two, although whenever a lane has more than one thread some of its units were
    /// traced ahead of their turn and added from records (float addition is not
    /// associative: a record added out of turn changes the last bits of its texels' sums).
    /// Two lanes on two threads trace in turn, recording nothing. A cancelled batch ends,
    /// on any thread count, with `Cancelled`.
    #[test]
    fn a_batch_adds_the_same_bits_whatever_the_thread_count() {
        for lanes in [1, 2] {
            let scene = cornell(20_000, lanes);
            let bundle = &scene.bundle;
            assert!(!bundle.emitters.small.is_empty(), "the lamp should get the light pass");
            let texels = TexelMap::build(&bundle.scene, &bundle.geom, &bundle.atlas, 0);
            let whole = WholeLod::new(&bundle.atlas, &texels);
            let target = whole.target(&texels);
            let own = crate::bundle::target::distinct_colours(texels.len());
            let source = SourceRadiance { own: &own, foreign: None };
            let jobs =
                JobSequence::new(bundle.config.seed, bundle.emitters.small.len(), bundle.config.light_directions);
            let batch: Vec<DirectionJob> = (0..4).map(|i| jobs.job(i)).collect();
            let never = AtomicBool::new(false);
            let bits = |s: &BatchSums| {
                let bundle: Vec<[u32; 4]> = s.bundle.iter().map(|b| b.map(f32::to_bits)).collect();
                let light: Vec<[u32; 3]> = s.light.iter().map(|l| l.to_array().map(f32::to_bits)).collect();
                (bundle, light)
            };
            let mut first = None;
            for threads in [1, 2, 3] {
                let mut backend = CpuBundleBackend::new(scene.clone(), threads);
                let mut sums = BatchSums::default();
                // Whether a thread gets ahead of its lane's unit due is up to the OS's
                // scheduling (on a loaded machine one thread may take every unit in turn):
                // batches are traced until one was, each one's sums checked.
                let mut recorded = false;
                for _attempt in 0..20 {
                    let stats = backend.trace_batch(&target, &batch, &source, &mut sums, &never).expect("batch");
                    assert!(sums.bundle.iter().any(|b| b[3] > 0.0) && sums.light.iter().any(|l| *l != Rgb::ZERO));
                    if threads <= lanes as usize {
                        assert_eq!(
                            stats.peak_recorded_hits, 0,
                            "{lanes} lanes, {threads} threads: a lane's one thread traces the unit due"
                        );
                    }
                    recorded |= stats.peak_recorded_hits > 0;
                    let b = bits(&sums);
                    match &first {
                        None => first = Some(b),
                        Some(f) => {
                            assert!(*f == b, "{lanes} lanes, {threads} threads: sums differ from one thread's")
                        }
                    }
                    if recorded || threads <= lanes as usize {
                        break;
                    }
                }
                assert!(
                    recorded || threads <= lanes as usize,
                    "{lanes} lanes, {threads} threads: no unit was traced ahead of its turn in 20 batches"
                );
                let cancel = AtomicBool::new(true);
                assert!(backend.trace_batch(&target, &batch, &source, &mut sums, &cancel).is_err());
            }
        }
    }
}
