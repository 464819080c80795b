//! Messy geometry as real assets have it, one small scene per cause: the bundle bake against
//! the reference path tracer, texel by texel.
//!
//! Every test compares a group of texels on the messy surface with a *control* group on a
//! clean surface of the same scene, lit the same way and sampled the same way: per texel the
//! relative error `(E_bundle − E_ref)/E_ref` (E as r + g + b), and per group its mean (the
//! bias) with the standard error of that mean (the spread of the per-texel errors over √n:
//! the texels' errors are independent draws of bundle and reference noise). A messy group
//! must show no more bias than the control beyond 4 combined standard errors (a false
//! failure once in ~16 000 runs), and no more per-texel spread than the control allows: the
//! same surfaces with the same sample counts have the same noise. Only whole texels (area a
//! full texel², away from edges and contacts) are compared, where the light over a texel is
//! smooth enough for its centre to stand for it.

use std::sync::Arc;

use livebake::bake::{BackendKind, BakeConfig, BakeOutput, bake};
use livebake::glam::Vec3;
use livebake::progress::NoProgress;
use livebake::reference::ReferenceTracer;
use livebake::scene::builder::diffuse;
use livebake::scene::{Rgb, Scene, SceneBuilder, SceneGeometry};

const TEXEL: f32 = 0.05;

fn bake_scene(scene: &Scene, directions: u32) -> BakeOutput {
    let mut c = BakeConfig { backend: BackendKind::Cpu, samples: directions, ..BakeConfig::default() };
    c.atlas.texel_size = Some(TEXEL);
    bake(&Arc::new(scene.clone()), &c, &NoProgress).expect("bake")
}

/// Whole texels (a full texel² of surface) of meshes `meshes` whose normal is `normal`,
/// with `keep(position)`, at most `max` of them, evenly spread.
fn texels_of(
    out: &BakeOutput,
    geom: &SceneGeometry,
    meshes: &[u32],
    normal: Vec3,
    keep: impl Fn(Vec3) -> bool,
    max: usize,
) -> Vec<usize> {
    let t = &out.lods[0].texels;
    let all: Vec<usize> = (0..t.len())
        .filter(|&i| {
            let tri = out.atlas.faces[t.face[i] as usize].tri as usize;
            meshes.contains(&geom.mesh[tri])
                && t.normal[i].dot(normal) > 0.999
                && t.area[i] >= 0.999 * TEXEL * TEXEL
                && keep(t.position[i])
        })
        .collect();
    let step = all.len().div_ceil(max).max(1);
    all.into_iter().step_by(step).collect()
}

/// Bias and spread of one group's per-texel relative errors against the reference.
#[derive(Debug)]
struct GroupError {
    texels: usize,
    mean: f64,
    /// Standard error of `mean`.
    se: f64,
    rms: f64,
}

fn group_error(out: &BakeOutput, tracer: &ReferenceTracer, picks: &[usize], spp: u32) -> GroupError {
    let t = &out.lods[0].texels;
    let queries: Vec<(Vec3, Vec3)> = picks.iter().map(|&i| (t.position[i], t.normal[i])).collect();
    let (reference, _) = tracer.irradiance_batch_estimates(&queries, spp, 5, &|_| {});
    let rel: Vec<f64> = picks
        .iter()
        .zip(&reference)
        .map(|(&i, r)| {
            let sum = |c: Rgb| (c.x + c.y + c.z) as f64;
            sum(out.lods[0].irradiance[i]) / sum(r.e) - 1.0
        })
        .collect();
    let n = rel.len() as f64;
    let mean = rel.iter().sum::<f64>() / n;
    let var = rel.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let rms = (rel.iter().map(|r| r * r).sum::<f64>() / n).sqrt();
    GroupError { texels: rel.len(), mean, se: (var / n).sqrt(), rms }
}

/// The messy group is estimated as well as the control: bias equal within 4 combined
/// standard errors; RMS error at most 1.25× the control's (with ≥ 100 texels per group an
/// RMS estimate is within ~7% of its value at 1σ, so the margin is > 3σ).
fn assert_as_good_as(name: &str, messy: &GroupError, control: &GroupError) {
    eprintln!("{name}: {messy:?} against control {control:?}");
    assert!(messy.texels >= 100 && control.texels >= 100, "{name}: too few texels");
    let bound = 4.0 * (messy.se.powi(2) + control.se.powi(2)).sqrt();
    assert!(
        (messy.mean - control.mean).abs() < bound,
        "{name}: bias {:.4} against the control's {:.4} (bound ±{bound:.4})",
        messy.mean,
        control.mean
    );
    assert!(
        messy.rms < 1.25 * control.rms,
        "{name}: RMS error {:.4} against the control's {:.4}",
        messy.rms,
        control.rms
    );
}

fn quad_y(y: f32, x0: f32, z0: f32, x1: f32, z1: f32, up: bool) -> [Vec3; 4] {
    let c = [Vec3::new(x0, y, z1), Vec3::new(x1, y, z1), Vec3::new(x1, y, z0), Vec3::new(x0, y, z0)];
    if up { c } else { [c[0], c[3], c[2], c[1]] }
}

/// Stacked coincident surfaces: a double-sided tile lying exactly on the floor (both fronts
/// up, same depth along every line) and an exact duplicate of the back wall, in a closed
/// room lit by a small lamp (the light pass) and a point light. Each copy is a surface a
/// renderer may show, and the reference tracer (which leaves every surface at p + ε·n)
/// sees the room from both: so must the bundles. Before layers, the copy a line listed
/// first looked into the other's back for half of all directions: the tile fronts read
/// 57% low here, and even the clean floor 7.5% low (the doubled wall sent half its light).
#[test]
fn stacked_copies_are_lit_as_one_surface() {
    let mut b = SceneBuilder::new();
    let wall = b.material(diffuse(Rgb::splat(0.6), Rgb::ZERO, false));
    let tile = b.material(diffuse(Rgb::splat(0.6), Rgb::ZERO, true));
    let lamp = b.material(diffuse(Rgb::ZERO, Rgb::splat(30.0), false));
    let (w, h) = (2.0, 1.5);
    b.cuboid("room", Vec3::ZERO, Vec3::new(w, h, w), true, wall); // mesh 0
    b.quad("tile", quad_y(0.0, 0.3, 0.3, 1.3, 1.3, true), tile); // mesh 1
    let back = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(w, 0.0, 0.0), Vec3::new(w, h, 0.0), Vec3::new(0.0, h, 0.0)];
    b.quad("back wall copy", back, wall); // mesh 2: the room's back wall again
    b.quad("lamp", quad_y(h - 0.05, 1.3, 1.3, 1.7, 1.7, false), lamp);
    b.point_light(Vec3::new(1.6, 1.0, 0.5), Rgb::splat(0.5));
    let scene = b.build();
    let geom = SceneGeometry::new(&scene);
    let out = bake_scene(&scene, 256);
    let tracer = ReferenceTracer::new(&scene);
    let spp = 1024;
    let on_tile = |p: Vec3| (0.3..1.3).contains(&p.x) && (0.3..1.3).contains(&p.z);
    let floor = |keep: &dyn Fn(Vec3) -> bool| texels_of(&out, &geom, &[0], Vec3::Y, keep, 150);
    let control = group_error(&out, &tracer, &floor(&|p| !on_tile(p)), spp);
    let tile_fronts = group_error(&out, &tracer, &texels_of(&out, &geom, &[1], Vec3::Y, |_| true, 150), spp);
    assert_as_good_as("tile fronts", &tile_fronts, &control);
    let under_tile = group_error(&out, &tracer, &floor(&|p| on_tile(p)), spp);
    assert_as_good_as("floor under the tile", &under_tile, &control);
    let walls = group_error(&out, &tracer, &texels_of(&out, &geom, &[0, 2], Vec3::Z, |_| true, 150), spp);
    let front_wall = group_error(&out, &tracer, &texels_of(&out, &geom, &[0], -Vec3::Z, |_| true, 150), spp);
    assert_as_good_as("back wall and its copy", &walls, &front_wall);
}
