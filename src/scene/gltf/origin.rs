//! Where the loaded scene's frame has its origin: models placed far from the file's origin
//! (a building exported in site or map coordinates, hundreds of kilometres out) are moved
//! next to it before positions become `f32`.
//!
//! Everything downstream holds positions in `f32`, whose spacing grows with the distance from
//! the origin: ~1 mm at 10 km, 8 mm at 100 km. There every vertex moves by up to half that,
//! each its own way (a light 1 cm below a ceiling, faces meant to meet edge to edge):
//! measured on the Cornell box moved by (d, 0, −d), the mean irradiance of a bake was 1–3%
//! off at d = 1–10 km, 16% at 100 km, and black at 4 000 km. So world transforms are
//! composed in `f64`
//! ([`super::nodes::NodeInstance::world64`]), the scene's centre is rounded to a multiple of
//! [`ORIGIN_STEP`], and positions, lights and cameras are made relative to it:
//! [`Scene::origin`](crate::scene::Scene::origin) is that point in the file's coordinates. A
//! scene whose centre lies within half a step of the file's origin keeps it (origin zero): it
//! is loaded exactly as before.

use ::gltf::json;
use glam::{DMat4, DVec3, Mat4};

use super::Ctx;
use super::nodes::{self, NodeInstance};
use super::primitive::position_accessor;

/// The grid the scene's origin is rounded to, metres: a scene centred within half of it from
/// the file's origin is not moved, and an origin on it is exact in `f32` up to 2³² m.
pub const ORIGIN_STEP: f64 = 256.0;

/// The farthest origin chosen, metres (2³²: beyond the Earth's circumference a hundred
/// times, and exact in `f32` on the step's grid).
pub const MAX_ORIGIN: f64 = 4_294_967_296.0;

/// The origin of the scene's frame, in the file's coordinates: the centre of the box of every
/// mesh instance (each primitive's POSITION `min`/`max`, through its world transform; a
/// primitive without them counts by its node's place), rounded to [`ORIGIN_STEP`].
pub(super) fn scene_origin(ctx: &Ctx, instances: &[NodeInstance]) -> Result<DVec3, super::LoadError> {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let mut grow = |p: DVec3| {
        if p.is_finite() {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    };
    for inst in instances {
        let Some(mesh) =
            ctx.root.nodes.get(inst.node).and_then(|n| n.mesh).and_then(|m| ctx.root.meshes.get(m.value()))
        else {
            continue;
        };
        let places: Vec<DMat4> = match nodes::instance_transforms(ctx, inst.node)? {
            None => vec![inst.world64],
            Some(transforms) => transforms.iter().map(|t| inst.world64 * t.as_dmat4()).collect(),
        };
        for prim in &mesh.primitives {
            let bounds = position_accessor(prim).and_then(|a| ctx.root.accessors.get(a)).and_then(accessor_bounds);
            for place in &places {
                match bounds {
                    Some((a, b)) => {
                        for k in 0..8 {
                            let corner = DVec3::new(
                                if k & 1 == 0 { a.x } else { b.x },
                                if k & 2 == 0 { a.y } else { b.y },
                                if k & 4 == 0 { a.z } else { b.z },
                            );
                            grow(place.transform_point3(corner));
                        }
                    }
                    None => grow(place.w_axis.truncate()),
                }
            }
        }
    }
    // Adding +0 turns the −0 of a centre just below zero into +0 (reports print "-0.0").
    let origin = ((lo + hi) * 0.5 / ORIGIN_STEP).round() * ORIGIN_STEP + DVec3::ZERO;
    // Past any map's coordinates a scene is not placed but broken: it loads as it is, and
    // positions that overflow are reported where they do.
    Ok(if lo.cmple(hi).all() && origin.abs().max_element() <= MAX_ORIGIN { origin } else { DVec3::ZERO })
}

/// `world64` (node → file coordinates) as a transform into the scene's frame, whose origin is
/// `origin`: the translation made relative in `f64`.
pub(super) fn relative64(world64: DMat4, origin: DVec3) -> DMat4 {
    let mut m = world64;
    m.w_axis -= origin.extend(0.0);
    m
}

/// [`relative64`] rounded to `f32` once.
pub(super) fn relative(world64: DMat4, origin: DVec3) -> Mat4 {
    relative64(world64, origin).as_mat4()
}

/// A POSITION accessor's `min` and `max` (glTF requires them), when both hold three finite
/// numbers.
fn accessor_bounds(accessor: &json::Accessor) -> Option<(DVec3, DVec3)> {
    let three = |v: &Option<json::Value>| -> Option<DVec3> {
        let a = v.as_ref()?.as_array()?;
        let n = |i: usize| a.get(i).and_then(json::Value::as_f64);
        let p = DVec3::new(n(0)?, n(1)?, n(2)?);
        p.is_finite().then_some(p)
    };
    Some((three(&accessor.min)?, three(&accessor.max)?))
}
