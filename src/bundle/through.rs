//! Light through surfaces along one bundle line: [`exchange`](super::estimator::exchange)
//! and [`emit`](super::estimator::emit) for lines that cross see-through surfaces (`BLEND`,
//! `KHR_materials_transmission`; docs/ARCHITECTURE.md "Light through surfaces").
//!
//! Every fragment has a transmittance T (per channel: what of the light meeting it passes
//! straight through, [`crate::scene::Sheet::pass`]; zero for an opaque surface). A side
//! sees, along its line, the faces of the layers ahead of it front to back, each weighed by
//! the running product of the T of the layers before it, and the sky behind the last:
//! `L_seen = Σ_k (Π_{j<k} T_j) L_k + (Π_j T_j) L_sky`. The walk stops at the first opaque
//! layer (its product is zero), so on a line without see-through surfaces it is the
//! neighbouring layer's face, exactly as `exchange` gives. A see-through surface's own
//! face shows only what it reflects (its texels' reflectance is α(1 − t)a); what passes it
//! is counted by the walk. Cut-outs (a `MASK` surface below its cutoff) are left out of the
//! list by the caller: no texel is lit there and no light stops. (A `BLEND` surface with
//! α = 0 stays: T = 1, it stops nothing, and its texels measure the light there.)
//!
//! **Layers.** A layer's T is the smallest of its members' (per channel): a pane stacked on
//! a wall is opaque, two copies of one pane are one pane (the layer is one surface).
//!
//! **Buried layers.** The rule of `exchange` (a layer whose neighbours on both sides show
//! it only backs of single-sided surfaces gets no hit) looks past see-through layers: the
//! neighbours are the nearest *opaque* layers on each side. The inside of a closed glass
//! box is open space (light passes its single-sided panes), and a face inside a solid stays
//! buried when a pane also lies inside the solid. The reference tracer's `is_buried` (the
//! punctual pass's 2×2 points) looks past see-through surfaces the same way.

use super::estimator::{CODE_MASK, Fragment, HitSink, Layering, NO_SIDE, layer_end, layer_face, minus_side, plus_side};
use super::sky::SkySeen;
use crate::scene::Rgb;

/// One layer of a pixel's list (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct Layer {
    start: u32,
    end: u32,
    /// What passes the layer; zero when opaque.
    pass: Rgb,
    /// The radiance of its face seen from before it (its sides looking −ω) and from after
    /// it (looking +ω), once looked up.
    face_minus: Option<Rgb>,
    face_plus: Option<Rgb>,
}

impl Layer {
    fn opaque(&self) -> bool {
        self.pass.max_element() <= 0.0
    }
}

/// Splits depth-sorted `frags` (with transmittances `pass`) into layers.
fn layers(frags: &[Fragment], pass: &[Rgb], l: Layering, out: &mut Vec<Layer>) {
    out.clear();
    let mut start = 0;
    while start < frags.len() {
        let end = layer_end(frags, start, l);
        let pass = pass[start..end].iter().fold(Rgb::ONE, |a, &t| a.min(t)).max(Rgb::ZERO);
        out.push(Layer { start: start as u32, end: end as u32, pass, face_minus: None, face_plus: None });
        start = end;
    }
}

fn members<'a>(frags: &'a [Fragment], layer: &Layer) -> &'a [Fragment] {
    &frags[layer.start as usize..layer.end as usize]
}

/// Whether no member's side (`side`) is a lit face.
fn blind(frags: &[Fragment], layer: &Layer, side: fn(&Fragment) -> u32) -> bool {
    members(frags, layer).iter().all(|f| side(f) & CODE_MASK == NO_SIDE)
}

/// Whether layer `k` is buried: the nearest opaque layers on both sides show it backs.
fn buried(frags: &[Fragment], layers: &[Layer], k: usize) -> bool {
    let behind = layers[..k].iter().rev().find(|l| l.opaque());
    let ahead = layers[k + 1..].iter().find(|l| l.opaque());
    behind.is_some_and(|l| blind(frags, l, plus_side)) && ahead.is_some_and(|l| blind(frags, l, minus_side))
}

/// What a side of layer `k` looking +ω (`ahead`) or −ω sees: the walk of the module docs.
fn seen_along(
    frags: &[Fragment],
    layers: &mut [Layer],
    k: usize,
    ahead: bool,
    sky: SkySeen,
    seen: &mut impl FnMut(u32) -> Rgb,
) -> Rgb {
    let (mut l, mut pass) = (Rgb::ZERO, Rgb::ONE);
    let mut j = k;
    loop {
        if ahead {
            j += 1;
            if j >= layers.len() {
                break;
            }
        } else if j == 0 {
            break;
        } else {
            j -= 1;
        }
        let layer = &mut layers[j];
        let span = &frags[layer.start as usize..layer.end as usize];
        let (cache, side): (_, fn(&Fragment) -> u32) =
            if ahead { (&mut layer.face_minus, minus_side) } else { (&mut layer.face_plus, plus_side) };
        let face =
            *cache.get_or_insert_with(|| layer_face(span, side, |_, code| Some(seen(code))).unwrap_or(Rgb::ZERO));
        l += pass * face;
        pass *= layer.pass;
        if pass.max_element() <= 0.0 {
            return l;
        }
    }
    l + pass * if ahead { sky.ahead } else { sky.behind }
}

/// [`exchange`](super::estimator::exchange) over a line whose fragments pass `pass[i]`
/// (see the module docs; `pass` in the order of `frags`). `scratch` is reused across pixels.
#[allow(clippy::too_many_arguments)]
pub fn exchange_through(
    frags: &[Fragment],
    pass: &[Rgb],
    l: Layering,
    a_px: f32,
    sky: SkySeen,
    mut seen: impl FnMut(u32) -> Rgb,
    sink: &mut impl HitSink,
    scratch: &mut Vec<Layer>,
) {
    layers(frags, pass, l, scratch);
    for k in 0..scratch.len() {
        if buried(frags, scratch, k) {
            continue;
        }
        let (mut l_ahead, mut l_behind) = (None, None);
        let layer = scratch[k];
        for f in members(frags, &layer) {
            if let Some(t) = f.plus_texel() {
                let l = match l_ahead {
                    Some(l) => l,
                    None => *l_ahead.insert(seen_along(frags, scratch, k, true, sky, &mut seen)),
                };
                sink.hit(t, l * a_px, a_px);
            }
            if let Some(t) = f.minus_texel() {
                let l = match l_behind {
                    Some(l) => l,
                    None => *l_behind.insert(seen_along(frags, scratch, k, false, sky, &mut seen)),
                };
                sink.hit(t, l * a_px, a_px);
            }
        }
    }
}

/// [`emit`](super::estimator::emit) over a line whose fragments pass `pass[i]`: an emitter
/// layer's light reaches the target sides facing it on every layer along its way, weighed
/// by the product of the T of the layers between, up to the first opaque one.
pub fn emit_through(
    frags: &[Fragment],
    pass: &[Rgb],
    l: Layering,
    a_px: f32,
    mut emission: impl FnMut(u32) -> Rgb,
    sink: &mut impl HitSink,
    scratch: &mut Vec<Layer>,
) {
    layers(frags, pass, l, scratch);
    let emitted = |layer: &Layer, side: fn(&Fragment) -> u32, emission: &mut dyn FnMut(u32) -> Rgb| {
        layer_face(members(frags, layer), side, |f, code| f.is_emitter().then(|| emission(code)))
    };
    for j in 0..scratch.len() {
        // Toward +ω: the sides looking −ω of the layers ahead.
        if let Some(le) = emitted(&scratch[j], plus_side, &mut emission) {
            let mut pass = Rgb::ONE;
            for layer in &scratch[j + 1..] {
                for dst in members(frags, layer).iter().filter_map(Fragment::minus_texel) {
                    sink.hit(dst, pass * le * a_px, a_px);
                }
                pass *= layer.pass;
                if pass.max_element() <= 0.0 {
                    break;
                }
            }
        }
        // Toward −ω: the sides looking +ω of the layers behind.
        if let Some(le) = emitted(&scratch[j], minus_side, &mut emission) {
            let mut pass = Rgb::ONE;
            for layer in scratch[..j].iter().rev() {
                for dst in members(frags, layer).iter().filter_map(Fragment::plus_texel) {
                    sink.hit(dst, pass * le * a_px, a_px);
                }
                pass *= layer.pass;
                if pass.max_element() <= 0.0 {
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
