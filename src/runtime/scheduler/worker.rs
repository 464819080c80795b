//! The worker loop: take a job, trace a unit, publish or park the bake.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use crate::bundle::BundleBackend;
use crate::runtime::RuntimeEvent;
use crate::runtime::cell_bake::CellBake;

use super::pick::{Job, pick};
use super::publish::{Due, publish, publish_due, shown_now};
use super::punctual_jobs::bake_punctual;
use super::{Shared, State, sync_camera};

pub(in crate::runtime) fn worker(shared: &Shared) {
    let mut backend: Option<(u64, Box<dyn BundleBackend>)> = None;
    let cancel = &shared.shutdown;
    loop {
        // Take the most urgent job.
        let job = {
            let mut st = shared.lock();
            loop {
                if shared.shutdown.load(Ordering::SeqCst) {
                    return;
                }
                sync_camera(shared, &mut st);
                if st.first_light && !st.paused && !st.relighting && st.failed.is_none() {
                    if let Some(job) = pick(shared, &mut st) {
                        break job;
                    }
                }
                st = shared.wake.wait_timeout(st, Duration::from_millis(200)).unwrap_or_else(|e| e.into_inner()).0;
            }
        };
        let (world, generation, cells, lod, bake) = match job {
            Job::Bundles { world, generation, cells, lod, bake } => (world, generation, cells, lod, bake),
            Job::Punctual { world, generation, cell, levels } => {
                bake_punctual(shared, &world, generation, cell, &levels);
                continue;
            }
        };
        if backend.as_ref().is_none_or(|(g, _)| *g != generation) {
            match (shared.make_backend)(&world.bundle, 1) {
                Ok(b) => backend = Some((generation, b)),
                Err(e) => {
                    shared.emit(RuntimeEvent::Failed { error: e.to_string() });
                    let mut st = shared.lock();
                    for &c in &cells {
                        st.cells[c as usize].busy = false;
                    }
                    return;
                }
            }
        }
        let Some((_, backend)) = backend.as_mut() else { return };
        let mut bake = match bake {
            Some(b) => b,
            None => {
                let t = Instant::now();
                let b = Box::new(CellBake::new(&world, &cells, lod, shared.shown(), shared.seed()));
                let mut st = shared.lock();
                st.bake_bytes += b.bytes() as u64;
                st.stats.cell_setup_seconds += t.elapsed().as_secs_f64();
                b
            }
        };
        let unit = bake.step(&world, backend.as_mut(), shared.config.unit_directions, cancel);
        let mut st = shared.lock();
        if st.generation != generation {
            // A hot reload replaced the world: this bake's texels are of the old scene (the
            // reload recounted the bytes of what it kept). The grid is kept across reloads.
            for &c in &cells {
                if let Some(s) = st.cells.get_mut(c as usize) {
                    s.busy = false;
                }
            }
            continue;
        }
        let u = match unit {
            Ok(u) => u,
            Err(_) => {
                // Cancelled (shutting down): the bake keeps what it had before the unit.
                park(&mut st, bake);
                continue;
            }
        };
        st.stats.pass.add(&u.pass);
        st.stats.units += 1;
        st.stats.directions_traced += u.directions;
        st.window_samples += u.texel_samples;
        let c = &shared.config;
        let error = bake.error();
        let d = bake.directions();
        let due = publish_due(c, bake.lod, shown_now(&st, &bake), d, error);
        if due == Due::Wait {
            park(&mut st, bake);
        } else {
            let settled = due == Due::Settled;
            let refined = publish(shared, &mut st, &bake, error, settled);
            let (cells, lod) = (bake.cells.clone(), bake.lod);
            if settled {
                st.bake_bytes -= bake.bytes() as u64;
                for &m in &bake.cells {
                    let s = &mut st.cells[m as usize];
                    s.busy = false;
                    s.member_of = None;
                    s.baking_directions = 0;
                }
            } else {
                // Published early: the bake goes on at this LOD into the same sums, parked as
                // between any two units (its memory stays reserved: the budget counted its
                // pages and its bake together).
                park(&mut st, bake);
            }
            drop(st);
            for &cell in &cells {
                shared.emit(RuntimeEvent::CellPublished {
                    cell,
                    lod,
                    directions: d,
                    error,
                    settled,
                    group: cells.clone(),
                });
            }
            if let Some(ms) = refined {
                shared.emit(RuntimeEvent::ReloadRefined { ms, directions: c.bundle.directions });
            }
        }
        shared.wake.notify_all();
    }
}

/// Puts a bake back between units: in its leader's slot, its cells free for the next unit.
fn park(st: &mut State, bake: Box<CellBake>) {
    let leader = bake.leader();
    for &m in &bake.cells {
        let s = &mut st.cells[m as usize];
        s.busy = false;
        s.baking_directions = bake.directions();
        s.member_of = (m != leader).then_some(leader);
    }
    st.cells[leader as usize].bake = Some(bake);
}
