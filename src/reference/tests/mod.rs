//! Tests of the reference tracer: BVH against brute force, analytic irradiance cases,
//! sidedness and transport, batches. Tolerances are derived in comments next to each check.

mod batch;
mod bvh;
mod emissive;
mod glass;
mod lights;
mod transport;

use glam::Vec3;

use crate::reference::tracer::{IrradianceEstimate, ReferenceTracer};
use crate::scene::Rgb;

/// Checks a Monte Carlo estimate against an exact value, per channel:
/// `|E − exact| ≤ 5σ + floor·|exact|` and `σ ≤ max_rel_stderr·|exact|`.
/// σ is the estimate's standard error (s/√N from the N paths' own sample variance; a correct
/// estimator falls outside 5σ with probability ~6e-7). `floor` covers what is not noise:
/// f32 rounding (1e-5) or, for area lights, that rays start at p + ε·n (a relative shift of
/// order 2ε/d for a source at distance d; see the tracer docs). Bounding σ keeps the check's
/// power: a biased estimator cannot hide behind a large variance.
#[track_caller]
pub(super) fn assert_estimate(est: &IrradianceEstimate, exact: Rgb, max_rel_stderr: f32, floor: f32, what: &str) {
    for c in 0..3 {
        let (e, x, s) = (est.e[c], exact[c], est.stderr[c]);
        assert!(s <= max_rel_stderr * x.abs(), "{what}: channel {c}: stderr {s} too large for {x} (E = {e})");
        let dev = (e - x) / s.max(1e-30);
        assert!(
            (e - x).abs() <= 5.0 * s + floor * x.abs(),
            "{what}: channel {c}: E = {e} ± {s}, exact {x} ({dev:.2}σ)"
        );
    }
}

/// E at (p, n) with `spp` paths, stream derived from the point so different checks differ.
pub(super) fn estimate(t: &ReferenceTracer<'_>, p: Vec3, n: Vec3, spp: u32) -> IrradianceEstimate {
    let stream =
        (p.x.to_bits() as u64) ^ ((p.y.to_bits() as u64) << 21) ^ ((p.z.to_bits() as u64) << 42) ^ n.x.to_bits() as u64;
    t.irradiance_estimate(p, n, spp, 0x5eed, stream)
}
