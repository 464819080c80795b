//! KHR_lights_punctual lights and cameras attached to nodes, placed in world space.

use std::f32::consts::FRAC_PI_2;

use ::gltf::json;
use glam::{Vec3, Vec4Swizzles};
use json::extensions::scene::khr_lights_punctual::{Light as JsonLight, Type as LightType};
use json::validation::Checked;

use super::diag::{Diagnostics, Kind};
use super::nodes::{NodeInstance, node_name};
use super::{Ctx, LoadError};
use crate::scene::radiometry::LightCeiling;
use crate::scene::{Camera, LightKind, Projection, PunctualLight};

/// The light on node `inst`, if it has one.
pub(super) fn light_of(
    ctx: &Ctx,
    diag: &mut Diagnostics,
    inst: &NodeInstance,
) -> Result<Option<PunctualLight>, LoadError> {
    let Some(node) = ctx.root.nodes.get(inst.node) else { return Ok(None) };
    let Some(index) = node.extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref()).map(|l| l.light.value())
    else {
        return Ok(None);
    };
    let light = ctx
        .root
        .extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .and_then(|l| l.lights.get(index))
        .ok_or_else(|| ctx.invalid(format!("node {}: KHR_lights_punctual light {index} does not exist", inst.node)))?;
    let name = light.name.clone().unwrap_or_else(|| node_name(ctx, inst.node));
    let bad = |what: &str| ctx.invalid(format!("light {index} '{name}': {what}"));
    let kind = match light.type_ {
        Checked::Valid(LightType::Directional) => LightKind::Directional,
        Checked::Valid(LightType::Point) => LightKind::Point,
        Checked::Valid(LightType::Spot) => spot_cones(light, diag, &name).map_err(|w| bad(&w))?,
        Checked::Invalid => return Err(bad("invalid type")),
    };
    let color = Vec3::from(light.color);
    if !color.is_finite() || !light.intensity.is_finite() || color.min_element() < 0.0 || light.intensity < 0.0 {
        return Err(bad("color and intensity must be finite and non-negative"));
    }
    let position = inst.world.w_axis.xyz();
    let direction = inst.world.transform_vector3(Vec3::NEG_Z).try_normalize();
    let direction = match (kind, direction) {
        (_, Some(d)) => d,
        (LightKind::Point, None) => Vec3::NEG_Z,
        (_, None) => {
            diag.note(Kind::LightSkipped, 1, || format!("{name}: its node transform has no direction (zero scale)"));
            return Ok(None);
        }
    };
    Ok(Some(PunctualLight {
        name: name.clone(),
        kind,
        intensity: color * light.intensity,
        position,
        direction,
        range: range(light, kind, diag, &name),
    }))
}

/// Refuses the scene when a light is brighter than `ceiling` lets each of them be (the
/// scene's surface area must keep the sums' weights finite first).
pub(super) fn check_brightness(ctx: &Ctx, lights: &[PunctualLight], ceiling: &LightCeiling) -> Result<(), LoadError> {
    if !ceiling.area_fits() {
        return Err(ctx.invalid(format!(
            "the scene's triangles cover {:.3e} m², more than the {:.2e} m² the estimator's f32 sums can weigh: its \
             coordinates are too large",
            ceiling.area,
            LightCeiling::most_area()
        )));
    }
    for (i, light) in lights.iter().enumerate() {
        let directional = matches!(light.kind, LightKind::Directional);
        let unit = if directional { "W/m²" } else { "W/sr" };
        let value = light.intensity.max_element() as f64;
        ceiling
            .check(
                || format!("light {i} '{}': intensity (colour × intensity)", light.name),
                value,
                ceiling.light_intensity(directional, lights.len()),
                unit,
            )
            .map_err(|e| ctx.invalid(e.to_string()))?;
    }
    Ok(())
}

/// glTF `range` for point and spot lights; zero, negative or non-finite ranges are dropped
/// (unlimited) with a warning. Directional lights have no range.
fn range(light: &JsonLight, kind: LightKind, diag: &mut Diagnostics, name: &str) -> Option<f32> {
    let r = light.range?;
    if kind == LightKind::Directional {
        return None;
    }
    if r.is_finite() && r > 0.0 {
        return Some(r);
    }
    diag.note(Kind::LightParameter, 1, || format!("{name}: range {r} ignored"));
    None
}

/// Cone angles (defaults 0 and π/4), brought into 0 ≤ inner ≤ outer ≤ π/2 with a warning.
fn spot_cones(light: &JsonLight, diag: &mut Diagnostics, name: &str) -> Result<LightKind, String> {
    let (inner, outer) =
        light.spot.as_ref().map_or((0.0, std::f32::consts::FRAC_PI_4), |s| (s.inner_cone_angle, s.outer_cone_angle));
    if !inner.is_finite() || !outer.is_finite() {
        return Err("spot cone angles are not finite".into());
    }
    let outer_c = outer.clamp(0.0, FRAC_PI_2);
    let inner_c = inner.clamp(0.0, outer_c);
    if (inner_c, outer_c) != (inner, outer) {
        diag.note(Kind::LightParameter, 1, || {
            format!("{name}: cone angles ({inner}, {outer}) clamped to ({inner_c}, {outer_c})")
        });
    }
    Ok(LightKind::Spot { inner_cone: inner_c, outer_cone: outer_c })
}

/// The camera on node `inst`, if it has one. Scale (and any mirroring) is dropped from the
/// world transform: a camera has only a position and an orientation.
pub(super) fn camera_of(ctx: &Ctx, diag: &mut Diagnostics, inst: &NodeInstance) -> Result<Option<Camera>, LoadError> {
    let Some(index) = ctx.root.nodes.get(inst.node).and_then(|n| n.camera).map(|c| c.value()) else {
        return Ok(None);
    };
    let cam = ctx
        .root
        .cameras
        .get(index)
        .ok_or_else(|| ctx.invalid(format!("node {}: camera {index} does not exist", inst.node)))?;
    let name = cam.name.clone().unwrap_or_else(|| node_name(ctx, inst.node));
    let bad = |what: &str| ctx.invalid(format!("camera {index} '{name}': {what}"));
    let projection = match (&cam.type_, &cam.perspective, &cam.orthographic) {
        (Checked::Valid(json::camera::Type::Perspective), Some(p), _) => {
            Projection::Perspective { yfov: p.yfov, aspect: p.aspect_ratio, znear: p.znear, zfar: p.zfar }
        }
        (Checked::Valid(json::camera::Type::Orthographic), _, Some(o)) => {
            Projection::Orthographic { xmag: o.xmag, ymag: o.ymag, znear: o.znear, zfar: o.zfar }
        }
        _ => return Err(bad("its type does not match its perspective/orthographic properties")),
    };
    let (_scale, rotation, position) = inst.world.to_scale_rotation_translation();
    let Some(rotation) = Some(rotation.normalize()).filter(|r| r.is_finite()) else {
        diag.note(Kind::CameraSkipped, 1, || format!("{name}: its node transform has no orientation"));
        return Ok(None);
    };
    Ok(Some(Camera { name, position, rotation, projection }))
}
