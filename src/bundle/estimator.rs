//! The radiance exchange along one bundle ray (docs/ARCHITECTURE.md "Units and the estimator").
//!
//! A pixel's fragments, ordered by depth along ω, are the surfaces one bundle line crosses.
//! Between two consecutive fragments, each sees the other: the side of fragment i that looks
//! along +ω sees the side of fragment i+1 that looks along −ω, and vice versa; the first and
//! last sides see the sky (the first side looking −ω sees it behind, the last looking +ω ahead). A side that is not a lit face (the back of a single-sided surface:
//! the inside of closed geometry) is black and receives nothing — that is what stops leaks.
//!
//! **Layers.** Coplanar surfaces facing the same way at the same depth along a line are
//! one surface for it: such fragments form a *layer* (see [`Coincidence`]), and light is
//! exchanged between consecutive layers, never inside one. Every side of a layer that looks
//! along +ω sees the next layer's face (the brightest of its sides that look −ω and are lit
//! faces; black when it has none), and every side looking −ω sees the previous layer's
//! face. Real assets are full of such stacks: tiles or rugs modelled on the floor, an
//! emissive quad on a ceiling, duplicated meshes, z-fighting copies a fraction of a
//! millimetre apart. Without layers, the copy a line happens to list first looks straight
//! at the other's back and sees black, for half of all directions: a tile on a floor got
//! 46% of its light, a lamp on its ceiling lost half its emission. Only coplanar fragments
//! join: surfaces that merely pass close to each other (at an edge or a corner, where a
//! room's floor meets its neighbour's wall) keep their depth order, or a layer would let
//! one see past the other. Two rooms sharing a zero-thickness wall (coplanar but facing
//! apart) stay two layers, ordered by facing (see [`sort_by_depth`]): the backs face each
//! other and no light crosses.
//!
//! A side is coded in 31 bits: a texel of the bake's target (below [`FOREIGN`]), a lit face
//! outside the target (`FOREIGN + k`, k naming the fragment's triangle for whoever resolves
//! it: its radiance is looked up, it receives nothing), or [`NO_SIDE`].
//!
//! Every hit on a target texel adds `a_px · L_seen` and `a_px` to it; its irradiance is then
//! the self-normalising `E = π · Σ a·L / Σ a` (hits are cosine-distributed because a texel's
//! projected area is ∝ |n·ω|).
//!
//! **Buried layers.** A layer whose neighbours on both sides show it only backs of
//! single-sided surfaces lies inside closed geometry: a face running through a solid
//! (a slab through a floor, a prop sunk into a wall, the parts of real assets that
//! intersect). Those stretches of a texel are never seen, so their lines give no hit at all
//! (rather than black ones): the texel's estimate is that of its visible part. A texel
//! wholly inside gets none (see [`crate::bundle::progressive`] for how it is shown). On
//! zdm2 (a real game map) at 0.25 m texels this took the error at 96 points against
//! Mitsuba from 7.0% to 4.6% (mean bias −2.3% to +0.1%), the same directions.
//!
//! The light pass uses the same layers but only emitter faces give: the sides facing a
//! layer whose face emits receive `a_px · Le`, normalised later by the texel's area.
//!
//! These functions are the spec the GPU resolve shader is held equal to.

use glam::Vec3;

use super::sky::SkySeen;
use crate::scene::Rgb;

/// "No texel": the side is not a lit face.
pub const NO_SIDE: u32 = 0x7FFF_FFFF;
/// Codes from here up to [`NO_SIDE`] are foreign sides: `FOREIGN + k`.
pub const FOREIGN: u32 = 0x4000_0000;
/// Set on `plus` of fragments that belong to the emitter group of a light pass.
pub const EMITTER_FLAG: u32 = 0x8000_0000;
/// Set on `minus` when the triangle's front face looks along +ω.
pub const FRONT_LOOKS_PLUS: u32 = 0x8000_0000;
pub(super) const CODE_MASK: u32 = 0x7FFF_FFFF;

/// The 31-bit code of a side (flags removed).
#[inline]
pub fn side_code(side: u32) -> u32 {
    side & CODE_MASK
}

/// Whether a side code names a target texel.
#[inline]
pub fn is_own(code: u32) -> bool {
    code < FOREIGN
}

/// One surface crossing of a bundle line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fragment {
    /// Position along ω (metres, any fixed origin).
    pub depth: f32,
    /// Code of the side looking along +ω (module docs); may carry [`EMITTER_FLAG`].
    pub plus: u32,
    /// Code of the side looking along −ω; may carry [`FRONT_LOOKS_PLUS`].
    pub minus: u32,
    /// The triangle's unit front normal in the bundle frame (along t, b, ω; see
    /// [`BundleFrame::coords`](super::raster::BundleFrame::coords)), [`pack_normal`]ed:
    /// which fragments are coplanar, and how steeply their depth changes.
    pub normal: u32,
}

impl Fragment {
    /// The target texel of the side looking along +ω, if it is one.
    #[inline]
    pub fn plus_texel(&self) -> Option<u32> {
        let t = self.plus & CODE_MASK;
        is_own(t).then_some(t)
    }

    /// The target texel of the side looking along −ω, if it is one.
    #[inline]
    pub fn minus_texel(&self) -> Option<u32> {
        let t = self.minus & CODE_MASK;
        is_own(t).then_some(t)
    }

    /// Order of coincident surfaces: the one whose front looks back along −ω first.
    #[inline]
    fn coincident_rank(&self) -> u32 {
        self.minus >> 31
    }

    #[inline]
    pub fn is_emitter(&self) -> bool {
        self.plus & EMITTER_FLAG != 0
    }
}

/// Octahedral encoding of a unit vector in 2 × 16 bits (Cigolle et al., JCGT 2014):
/// about 5·10⁻⁵ rad of resolution, far below [`COPLANAR_COS`].
pub fn pack_normal(n: Vec3) -> u32 {
    let n = n / (n.x.abs() + n.y.abs() + n.z.abs()).max(f32::MIN_POSITIVE);
    let folded = |a: f32, b: f32| (1.0 - b.abs()) * if a >= 0.0 { 1.0 } else { -1.0 };
    let (u, v) = if n.z >= 0.0 { (n.x, n.y) } else { (folded(n.x, n.y), folded(n.y, n.x)) };
    let q = |x: f32| ((x.clamp(-1.0, 1.0) * 0.5 + 0.5) * 65535.0).round() as u32;
    q(u) | q(v) << 16
}

/// |n_ω| of the unit vector `packed` encodes (`unpack_normal(packed).z.abs()`), remembered
/// per thread for the last few normals: the coincidence tests ask it of the same few
/// surfaces pixel after pixel (a ceiling light's quad and the ceiling over the light pass's
/// whole footprint) and reject nearly every pair on it alone.
#[inline]
fn normal_cos(packed: u32) -> f32 {
    use std::cell::Cell;
    const SLOTS: usize = 64;
    // Keys are the packed normal widened: u64::MAX is no normal, so an empty slot never hits.
    thread_local! {
        static SEEN: [Cell<(u64, f32)>; SLOTS] = const { [const { Cell::new((u64::MAX, 0.0)) }; SLOTS] };
    }
    let slot = (packed ^ packed >> 16) as usize % SLOTS;
    SEEN.with(|seen| {
        let (key, cos) = seen[slot].get();
        if key == u64::from(packed) {
            return cos;
        }
        let cos = unpack_normal(packed).z.abs();
        seen[slot].set((u64::from(packed), cos));
        cos
    })
}

/// The unit vector [`pack_normal`] encoded.
pub fn unpack_normal(packed: u32) -> Vec3 {
    let d = |q: u32| (q & 0xFFFF) as f32 / 65535.0 * 2.0 - 1.0;
    let (u, v) = (d(packed), d(packed >> 16));
    let z = 1.0 - u.abs() - v.abs();
    let t = (-z).max(0.0);
    let x = u + if u >= 0.0 { -t } else { t };
    let y = v + if v >= 0.0 { -t } else { t };
    Vec3::new(x, y, z).normalize()
}

/// Fragments whose normals are closer than this (cosine of 10⁻³ rad) are coplanar when
/// they are at the same depth: copies of one surface are parallel to rounding (10⁻⁶);
/// faces that intersect at a visible angle are not one surface.
pub const COPLANAR_COS: f32 = 0.999_999_5;

/// When two fragments adjacent in depth order are one layer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coincidence {
    /// Depths within this are one place for [`sort_by_depth`], ordered by facing: two rooms
    /// sharing a zero-thickness wall, whose order rounding would decide (metres; a few f32
    /// ulps of the scene's coordinates). Kept small: it also catches lines grazing a
    /// concave edge, where the tie-break costs that line's sample.
    pub rounding: f32,
    /// Coplanar fragments facing the same way (fronts both looking +ω, or both −ω) closer
    /// than this along their normal are one layer: stacked copies. The scene's ray offset ε
    /// (see [`crate::reference::ray_epsilon`]), the gap the reference tracer and the
    /// Mitsuba cross-check step over, so that every estimator agrees on what one surface is.
    pub stacked: f32,
    /// Depth error per unit of depth slope of the rasteriser at this tile's pixel size
    /// ([`snapped_depth_slack`](super::raster::snapped_depth_slack)): what two coplanar
    /// fragments' depths may differ by besides their real gap.
    pub snap: f32,
}

impl Coincidence {
    /// Depth gaps beyond this are never a tie or a join, whatever the slope (up to 89.4°
    /// from the normal: |n_ω| ≥ 0.01; lines closer to grazing keep their depth order).
    #[inline]
    const fn reach(&self) -> f32 {
        self.rounding + 100.0 * (self.stacked + self.snap)
    }

    /// The gap along the normal `n` of two fragments `gap` apart in depth, and what
    /// rounding and snapping allow there (a depth gap Δ along ω is Δ·|n_ω| along the
    /// normal; the snapping error, slope tanθ times `snap` along ω, is `snap`·sinθ along it).
    #[inline]
    fn normal_gap(&self, gap: f32, cos: f32) -> (f32, f32) {
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        (gap * cos, self.rounding * cos + self.snap * sin)
    }

    /// [`Layering::same_place`] for a gap within reach: a line that crosses two surfaces this
    /// close is rare (a corner, a stack), so the normals are unpacked here, out of line, and
    /// never for the fragments a pixel's sort merely moves past.
    #[cold]
    #[inline(never)]
    fn parallel_within_slack(&self, a: &Fragment, b: &Fragment, gap: f32) -> bool {
        let (along, slack) = self.normal_gap(gap, normal_cos(a.normal));
        along <= slack && unpack_normal(a.normal).dot(unpack_normal(b.normal)).abs() >= COPLANAR_COS
    }

    /// [`Layering::joins`] for a gap within reach, out of line (see
    /// [`parallel_within_slack`](Self::parallel_within_slack)).
    #[cold]
    #[inline(never)]
    fn stacked_within_slack(&self, a: &Fragment, b: &Fragment, gap: f32) -> bool {
        let (along, slack) = self.normal_gap(gap, normal_cos(a.normal));
        along <= slack + self.stacked && unpack_normal(a.normal).dot(unpack_normal(b.normal)) >= COPLANAR_COS
    }
}

/// A tile's [`Coincidence`] with its reach (the depth gap beyond which no two fragments are a
/// tie or one layer) worked out once: what [`sort_by_depth`], [`exchange`] and [`emit`] read
/// for every pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Layering {
    c: Coincidence,
    reach: f32,
}

impl Coincidence {
    pub const fn layering(self) -> Layering {
        Layering { c: self, reach: self.reach() }
    }
}

impl Layering {
    /// Whether `a` and `b` are at one place along the line, for [`sort_by_depth`]: depths
    /// within rounding, or parallel surfaces (facing either way) within rounding and
    /// snapping.
    #[inline(always)]
    fn same_place(&self, a: &Fragment, b: &Fragment) -> bool {
        let gap = (b.depth - a.depth).abs();
        if gap <= self.c.rounding {
            return true;
        }
        gap <= self.reach && self.c.parallel_within_slack(a, b, gap)
    }

    /// Whether `b`, which follows `a` in depth order, lies in `a`'s layer: same facing,
    /// parallel, and closer along the normal than [`stacked`](Coincidence::stacked) once
    /// rounding and snapping are allowed for.
    #[inline(always)]
    fn joins(&self, a: &Fragment, b: &Fragment) -> bool {
        let gap = (b.depth - a.depth).abs();
        if gap > self.reach || a.coincident_rank() != b.coincident_rank() {
            return false;
        }
        self.c.stacked_within_slack(a, b, gap)
    }
}

/// Whether `a` lies before `b` along ω. Fragments at one place (see
/// [`Layering::same_place`]) are ordered by facing: the surface whose front looks back
/// along −ω goes first (its room lies before it). Two rooms sharing a zero-thickness wall
/// then never see each other, whatever order rounding or snapping would give their walls.
#[inline(always)]
fn before(a: &Fragment, b: &Fragment, l: &Layering) -> bool {
    if l.same_place(a, b) { a.coincident_rank() < b.coincident_rank() } else { a.depth < b.depth }
}

/// Sorts one pixel's fragments along ω (see `before`). Insertion sort: lists are short
/// (a few surfaces) and it is stable, so ties keep their deterministic build order.
#[inline]
pub fn sort_by_depth(frags: &mut [Fragment], l: Layering) {
    for i in 1..frags.len() {
        let f = frags[i];
        let mut j = i;
        while j > 0 && before(&f, &frags[j - 1], &l) {
            frags[j] = frags[j - 1];
            j -= 1;
        }
        frags[j] = f;
    }
}

/// The end (exclusive) of the layer that starts at `start` in depth-sorted `frags`.
#[inline]
pub(super) fn layer_end(frags: &[Fragment], start: usize, l: Layering) -> usize {
    let mut end = start + 1;
    while end < frags.len() && l.joins(&frags[end - 1], &frags[end]) {
        end += 1;
    }
    end
}

/// Whether no two fragments adjacent in depth order join (see [`Layering::joins`]): every
/// layer is then one fragment, the common case, which [`exchange`] and [`emit`] take without
/// looking for layers. Most lines meet surfaces far apart (beyond [`Coincidence::reach`],
/// one compare a pair); a line that meets two close surfaces, such as a lamp under its ceiling
/// or a slab through a floor, is still one fragment a layer unless they are stacked copies.
/// Where every layer is one fragment, the layered walk makes the same hits in the same order,
/// so which of the two runs is a matter of speed only.
#[inline(always)]
pub(super) fn one_fragment_layers(frags: &[Fragment], l: &Layering) -> bool {
    frags.windows(2).all(|w| !l.joins(&w[0], &w[1]))
}

/// The radiance a layer shows toward one side: the brightest (by r + g + b) of `radiance`
/// over its fragments whose side toward the viewer (`side(f)`: `f.minus` seen from before
/// the layer, `f.plus` from after it) is a lit face; `None` when it has none. Members of one
/// layer see the same light and differ only by albedo and emission: the one on top (an
/// emissive quad on a ceiling, a decal) is there to be seen. Ties go to the first.
#[inline]
pub(super) fn layer_face(
    layer: &[Fragment],
    side: impl Fn(&Fragment) -> u32,
    mut radiance: impl FnMut(&Fragment, u32) -> Option<Rgb>,
) -> Option<Rgb> {
    let mut best: Option<Rgb> = None;
    for f in layer {
        let code = side(f) & CODE_MASK;
        if code == NO_SIDE {
            continue;
        }
        if let Some(l) = radiance(f, code)
            && best.is_none_or(|b| l.element_sum() > b.element_sum())
        {
            best = Some(l);
        }
    }
    best
}

/// The side of a fragment seen from before its layer (a monomorphised argument of
/// [`layer_face`], so its loop is inlined where a function pointer was called per fragment).
#[inline(always)]
pub(super) fn minus_side(f: &Fragment) -> u32 {
    f.minus
}

/// The side of a fragment seen from after its layer.
#[inline(always)]
pub(super) fn plus_side(f: &Fragment) -> u32 {
    f.plus
}

/// Receives hits. `texel` is a lit face's texel.
pub trait HitSink {
    fn hit(&mut self, texel: u32, weighted_radiance: Rgb, weight: f32);
    /// Where the sink's per-texel sums lie, for a CPU resolve to prefetch them ahead of its
    /// hits; none by default.
    fn sums_layout(&self) -> TexelLayout {
        TexelLayout::NONE
    }
}

/// Where per-texel values lie in memory: texel t's at address `base + t · stride`. A hint
/// for prefetching only: nothing is ever read or written through it, so it holds addresses,
/// not pointers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TexelLayout {
    base: usize,
    stride: usize,
}

impl TexelLayout {
    /// No values to prefetch.
    pub const NONE: TexelLayout = TexelLayout { base: 0, stride: 0 };

    /// The layout of `values`, one a texel.
    pub fn of<T>(values: &[T]) -> Self {
        TexelLayout { base: values.as_ptr() as usize, stride: std::mem::size_of::<T>() }
    }

    /// The address of texel `t`'s value (`None` for [`NONE`](Self::NONE)).
    #[inline(always)]
    pub fn address(&self, t: u32) -> Option<usize> {
        (self.base != 0).then(|| self.base.wrapping_add(t as usize * self.stride))
    }
}

/// Global-bundle exchange over one pixel's depth-sorted fragments (sorted with
/// [`sort_by_depth`] and the same `l`): every target side receives the radiance of what it
/// sees (the neighbouring layer's face, module docs). `seen(code)`
/// is the outgoing radiance toward the bundle of the side with that code (target texel or
/// foreign; never called for [`NO_SIDE`], which is black, and only for faces some target
/// side sees). Hits arrive fragment by fragment, the side looking +ω first.
#[inline]
pub fn exchange(
    frags: &[Fragment],
    l: Layering,
    a_px: f32,
    sky: SkySeen,
    mut seen: impl FnMut(u32) -> Rgb,
    sink: &mut impl HitSink,
) {
    // Where every layer is one fragment, its side toward the viewer is its face. The hits of
    // fragment `f` whose neighbours show it the sides with codes `behind` and `ahead` (`None`:
    // the sky).
    // (A function, not a closure: a closure called from three places was not inlined.)
    #[inline(always)]
    fn one_fragment(
        f: &Fragment,
        (behind, ahead): (Option<u32>, Option<u32>),
        (a_px, sky): (f32, SkySeen),
        face: &mut impl FnMut(u32) -> Rgb,
        sink: &mut impl HitSink,
    ) {
        // Buried (see [`buried`]): both neighbours show it backs of single-sided faces.
        if behind == Some(NO_SIDE) && ahead == Some(NO_SIDE) {
            return;
        }
        if let Some(t) = f.plus_texel() {
            let l = ahead.map_or(sky.ahead, &mut *face);
            sink.hit(t, l * a_px, a_px);
        }
        if let Some(t) = f.minus_texel() {
            let l = behind.map_or(sky.behind, &mut *face);
            sink.hit(t, l * a_px, a_px);
        }
    }
    let mut face = |code: u32| if code == NO_SIDE { Rgb::ZERO } else { seen(code) };
    let mut one = |f: &Fragment, behind: Option<u32>, ahead: Option<u32>| {
        one_fragment(f, (behind, ahead), (a_px, sky), &mut face, sink)
    };
    // Most lines cross one or two surfaces (80% of the Cornell box's pixels, 70% of the Van
    // Gogh room's): the walk below, unrolled for them.
    match frags {
        [f] => return one(f, None, None),
        [f, g] if !l.joins(f, g) => {
            one(f, None, Some(g.minus & CODE_MASK));
            return one(g, Some(f.plus & CODE_MASK), None);
        }
        _ => {}
    }
    if one_fragment_layers(frags, &l) {
        // The code of the side the fragment before shows this one (its side looking +ω),
        // carried along; `None` before the first (the sky).
        let mut shown_behind = None;
        for (i, f) in frags.iter().enumerate() {
            let behind = shown_behind.replace(f.plus & CODE_MASK);
            one(f, behind, frags.get(i + 1).map(|a| a.minus & CODE_MASK));
        }
        return;
    }
    let mut start = 0;
    let mut end = if frags.is_empty() { 0 } else { layer_end(frags, 0, l) };
    // The layer before the current one; `None` before the first (the sky).
    let mut behind: Option<&[Fragment]> = None;
    while start < frags.len() {
        let next_end = if end < frags.len() { layer_end(frags, end, l) } else { end };
        let ahead = (end < frags.len()).then(|| &frags[end..next_end]);
        // What the layer's sides see, looked up once, when a target side needs it.
        let (mut l_ahead, mut l_behind) = (None, None);
        let layer = if buried(behind, ahead) { &frags[start..start] } else { &frags[start..end] };
        for f in layer {
            if let Some(t) = f.plus_texel() {
                let l = *l_ahead.get_or_insert_with(|| match ahead {
                    None => sky.ahead,
                    Some(layer) => layer_face(layer, minus_side, |_, code| Some(seen(code))).unwrap_or(Rgb::ZERO),
                });
                sink.hit(t, l * a_px, a_px);
            }
            if let Some(t) = f.minus_texel() {
                let l = *l_behind.get_or_insert_with(|| match behind {
                    None => sky.behind,
                    Some(layer) => layer_face(layer, plus_side, |_, code| Some(seen(code))).unwrap_or(Rgb::ZERO),
                });
                sink.hit(t, l * a_px, a_px);
            }
        }
        behind = Some(&frags[start..end]);
        (start, end) = (end, next_end);
    }
}

/// Whether a layer between `behind` and `ahead` (its neighbours along the line; `None`: the
/// sky) lies inside closed geometry: both neighbours are surfaces whose sides toward it are
/// not lit faces (backs of single-sided surfaces). A face passing through a solid (real
/// assets are full of intersecting pieces, slabs through floors, props sunk into walls)
/// has such stretches; they are never seen, so their hits would only darken the texel's
/// visible part.
#[inline]
fn buried(behind: Option<&[Fragment]>, ahead: Option<&[Fragment]>) -> bool {
    let blind = |layer: Option<&[Fragment]>, side: fn(&Fragment) -> u32| {
        layer.is_some_and(|l| l.iter().all(|f| side(f) & CODE_MASK == NO_SIDE))
    };
    blind(behind, plus_side) && blind(ahead, minus_side)
}

/// Light-pass exchange: where a layer's side faces an emitter of the light pass (fragments
/// carrying [`EMITTER_FLAG`]; the brightest when several), every target side of the
/// neighbouring layer facing it receives that emission. `emission(code)` is the emitted radiance of the side with that code
/// (zero if it does not emit).
#[inline]
pub fn emit(frags: &[Fragment], l: Layering, a_px: f32, mut emission: impl FnMut(u32) -> Rgb, sink: &mut impl HitSink) {
    // Where the layer's side facing the viewer (`side`) emits, its brightest emitter.
    #[inline(always)]
    fn emitted(
        layer: &[Fragment],
        side: impl Fn(&Fragment) -> u32,
        emission: &mut impl FnMut(u32) -> Rgb,
    ) -> Option<Rgb> {
        layer_face(layer, side, |f, code| f.is_emitter().then(|| emission(code)))
    }
    // Where every layer is one fragment, an emitter's side toward its neighbour is its face:
    // the hits between neighbours `before` and `layer`. (A function, not a closure, to be
    // inlined at each of its calls.)
    #[inline(always)]
    fn neighbours(
        before: &Fragment,
        layer: &Fragment,
        a_px: f32,
        emission: &mut impl FnMut(u32) -> Rgb,
        sink: &mut impl HitSink,
    ) {
        let mut emitted = |f: &Fragment, side: u32| match side & CODE_MASK {
            NO_SIDE => None,
            code => f.is_emitter().then(|| emission(code)),
        };
        if let Some(le) = emitted(before, before.plus)
            && let Some(dst) = layer.minus_texel()
        {
            sink.hit(dst, le * a_px, a_px);
        }
        if let Some(le) = emitted(layer, layer.minus)
            && let Some(dst) = before.plus_texel()
        {
            sink.hit(dst, le * a_px, a_px);
        }
    }
    // A light bundle's lines mostly cross an emitter and one surface on either side: the
    // walk below, unrolled for two and three fragments.
    match frags {
        [f, g] if !l.joins(f, g) => return neighbours(f, g, a_px, &mut emission, sink),
        [f, g, h] if !l.joins(f, g) && !l.joins(g, h) => {
            neighbours(f, g, a_px, &mut emission, sink);
            return neighbours(g, h, a_px, &mut emission, sink);
        }
        _ => {}
    }
    if one_fragment_layers(frags, &l) {
        for pair in frags.windows(2) {
            neighbours(&pair[0], &pair[1], a_px, &mut emission, sink);
        }
        return;
    }
    let mut start = 0;
    let mut previous: Option<&[Fragment]> = None;
    while start < frags.len() {
        let end = layer_end(frags, start, l);
        let layer = &frags[start..end];
        if let Some(before) = previous {
            if let Some(le) = emitted(before, plus_side, &mut emission) {
                for dst in layer.iter().filter_map(Fragment::minus_texel) {
                    sink.hit(dst, le * a_px, a_px);
                }
            }
            if let Some(le) = emitted(layer, minus_side, &mut emission) {
                for dst in before.iter().filter_map(Fragment::plus_texel) {
                    sink.hit(dst, le * a_px, a_px);
                }
            }
        }
        previous = Some(layer);
        start = end;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default)]
    struct Log(Vec<(u32, Rgb, f32)>);
    impl HitSink for Log {
        fn hit(&mut self, t: u32, l: Rgb, a: f32) {
            self.0.push((t, l, a));
        }
    }

    /// Tolerances of the tests: rounding 1e-4, stacked copies within 1e-3, no snapping.
    const C: Layering = Coincidence { rounding: 1e-4, stacked: 1e-3, snap: 0.0 }.layering();

    /// A fragment of a surface whose normal is +ω's (every test surface is parallel to
    /// the others unless it says otherwise).
    fn frag(depth: f32, plus: u32, minus: u32) -> Fragment {
        Fragment { depth, plus, minus, normal: pack_normal(Vec3::Z) }
    }

    #[test]
    fn sorting_is_stable_by_depth() {
        let mut f = vec![frag(3.0, 1, 1), frag(1.0, 2, 2), frag(3.0, 3, 3), frag(-1.0, 4, 4)];
        sort_by_depth(&mut f, Coincidence { rounding: 0.0, stacked: 0.0, snap: 0.0 }.layering());
        assert_eq!(f.iter().map(|f| f.plus).collect::<Vec<_>>(), vec![4, 2, 1, 3]);
    }

    /// Two rooms sharing a zero-thickness wall along ω: room A's wall (front looks −ω, into
    /// A) and room B's wall (front looks +ω, into B) at depths equal up to rounding. Whatever
    /// order they arrive in, A's wall comes first and neither room sees the other.
    #[test]
    fn coincident_back_to_back_walls_never_see_each_other() {
        let a_wall = frag(5.0 + 1e-6, NO_SIDE, 1); // plus = back (none), minus = front
        let b_wall = frag(5.0, 2, NO_SIDE | FRONT_LOOKS_PLUS);
        let a_floor = frag(0.0, 3, NO_SIDE);
        let b_far = frag(9.0, NO_SIDE, 4 | FRONT_LOOKS_PLUS);
        for order in [[a_floor, a_wall, b_wall, b_far], [a_floor, b_wall, a_wall, b_far]] {
            let mut f = order.to_vec();
            sort_by_depth(&mut f, C);
            assert_eq!(f[1], a_wall);
            let mut log = Log::default();
            // Room A's texels (1, 3) glow; room B's (2, 4) must see nothing of them.
            exchange(
                &f,
                C,
                1.0,
                SkySeen::uniform(Rgb::ZERO),
                |t| if t == 1 || t == 3 { Rgb::ONE } else { Rgb::ZERO },
                &mut log,
            );
            for (t, l, _) in log.0 {
                if t == 2 || t == 4 {
                    assert_eq!(l, Rgb::ZERO, "texel {t} of the dark room sees light");
                }
            }
        }
    }

    /// Two parallel walls: a floor (front looks +ω, texel 10) and a ceiling (front looks −ω,
    /// texel 20). Each sees the other; the outer sides are single-sided backs.
    #[test]
    fn facing_surfaces_exchange_and_backs_are_black() {
        let frags = [frag(0.0, 10, NO_SIDE), frag(2.0, NO_SIDE, 20)];
        let source = |t: u32| Rgb::splat(t as f32);
        let mut log = Log::default();
        exchange(&frags, C, 0.5, SkySeen::uniform(Rgb::splat(7.0)), source, &mut log);
        assert_eq!(log.0, vec![(10, Rgb::splat(10.0), 0.5), (20, Rgb::splat(5.0), 0.5)]);
    }

    /// A lit side looking at the back of a single-sided surface sees black; the outermost
    /// sides see the sky.
    #[test]
    fn sky_at_the_ends_and_black_from_single_sided_backs() {
        // A double-sided panel (texels 1 and 2) in front of a wall seen from behind.
        let frags = [frag(0.0, 1, 2), frag(1.0, 3, NO_SIDE)];
        let mut log = Log::default();
        exchange(&frags, C, 1.0, SkySeen::uniform(Rgb::splat(4.0)), |t| Rgb::splat(t as f32 * 100.0), &mut log);
        assert_eq!(log.0, vec![(1, Rgb::ZERO, 1.0), (2, Rgb::splat(4.0), 1.0), (3, Rgb::splat(4.0), 1.0)]);
    }

    /// An environment is seen by direction: the last side looking +ω sees the sky ahead (in
    /// direction ω), the first looking −ω the sky behind (in direction −ω).
    #[test]
    fn the_ends_see_the_sky_in_their_own_direction() {
        let sky = SkySeen { ahead: Rgb::splat(4.0), behind: Rgb::splat(9.0) };
        let mut log = Log::default();
        exchange(&[frag(0.0, 1, 2)], C, 1.0, sky, |_| Rgb::ZERO, &mut log);
        assert_eq!(log.0, vec![(1, Rgb::splat(4.0), 1.0), (2, Rgb::splat(9.0), 1.0)]);
    }

    /// A floor (texel 5, looks +ω) running through a closed box (bottom texel 8 looks −ω,
    /// top texel 9 looks +ω, both outward): inside the box the floor's line sees only the
    /// box's backs on both sides, so it gets no hit; the box's own faces still see the sky.
    /// Where only one side is a back (a wall seen from behind across open space, the sky on
    /// the other side) the floor takes its black hit as before.
    #[test]
    fn a_face_inside_closed_geometry_gets_no_hit() {
        let bottom = frag(0.0, NO_SIDE, 8);
        let floor = frag(0.5, 5, NO_SIDE | FRONT_LOOKS_PLUS);
        let top = frag(1.0, 9, NO_SIDE | FRONT_LOOKS_PLUS);
        let mut log = Log::default();
        exchange(&[bottom, floor, top], C, 1.0, SkySeen::uniform(Rgb::splat(4.0)), |t| Rgb::splat(t as f32), &mut log);
        assert_eq!(log.0, vec![(8, Rgb::splat(4.0), 1.0), (9, Rgb::splat(4.0), 1.0)]);
        let wall_back = frag(1.0, NO_SIDE, NO_SIDE | FRONT_LOOKS_PLUS);
        let mut log = Log::default();
        exchange(&[floor, wall_back], C, 1.0, SkySeen::uniform(Rgb::splat(4.0)), |t| Rgb::splat(t as f32), &mut log);
        assert_eq!(log.0, vec![(5, Rgb::ZERO, 1.0)]);
    }

    #[test]
    fn emitters_light_only_the_facing_neighbours() {
        // Lamp (emitter, emits along −ω only: its minus side is lit, plus is a single-sided
        // back) above a floor whose plus side faces the lamp; a wall beyond the lamp.
        let frags = [
            frag(0.0, 5, NO_SIDE),                // floor, looks +ω at the lamp
            frag(1.0, NO_SIDE | EMITTER_FLAG, 6), // lamp, emitting side looks −ω
            frag(2.0, NO_SIDE, 7),                // ceiling beyond, looks −ω at the lamp's back
        ];
        let mut log = Log::default();
        emit(&frags, C, 0.25, |t| if t == 6 { Rgb::splat(8.0) } else { Rgb::ZERO }, &mut log);
        assert_eq!(log.0, vec![(5, Rgb::splat(2.0), 0.25)]);
    }

    /// Every input order of `frags`, sorted as the resolve sorts them.
    fn orders(frags: &[Fragment]) -> Vec<Vec<Fragment>> {
        let mut out = Vec::new();
        let n = frags.len();
        let mut idx: Vec<usize> = (0..n).collect();
        // Heap's algorithm over the few fragments of a test.
        fn permute(k: usize, idx: &mut Vec<usize>, frags: &[Fragment], out: &mut Vec<Vec<Fragment>>) {
            if k <= 1 {
                let mut f: Vec<Fragment> = idx.iter().map(|&i| frags[i]).collect();
                sort_by_depth(&mut f, C);
                out.push(f);
                return;
            }
            for i in 0..k {
                permute(k - 1, idx, frags, out);
                idx.swap(if k % 2 == 0 { i } else { 0 }, k - 1);
            }
        }
        permute(n, &mut idx, frags, &mut out);
        out
    }

    /// A floor (single-sided, front looks +ω: texel 1) with a double-sided tile on it
    /// (front 2, back 3), 5e-4 apart (a stacked copy, inside `C.stacked`), under a glowing
    /// ceiling (texel 9, front looks −ω). Whatever order the copies arrive in, both fronts
    /// see the ceiling, the tile's back sees the sky below, and the ceiling sees the
    /// brighter of the two fronts.
    #[test]
    fn stacked_copies_are_one_layer() {
        let floor = frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS);
        let tile = frag(5e-4, 2, 3 | FRONT_LOOKS_PLUS);
        let ceiling = frag(2.0, NO_SIDE, 9);
        let radiance = |t: u32| Rgb::splat(t as f32);
        for f in orders(&[floor, tile, ceiling]) {
            let mut log = Log::default();
            exchange(&f, C, 1.0, SkySeen::uniform(Rgb::splat(0.5)), radiance, &mut log);
            log.0.sort_by_key(|h| h.0);
            assert_eq!(
                log.0,
                vec![
                    (1, Rgb::splat(9.0), 1.0),
                    (2, Rgb::splat(9.0), 1.0),
                    (3, Rgb::splat(0.5), 1.0),
                    (9, Rgb::splat(2.0), 1.0)
                ],
                "{f:?}"
            );
        }
        // Further apart than `C.stacked`, the tile is a surface of its own: the floor under
        // it looks at the tile's back.
        let mut f = vec![floor, frag(2e-3, 2, 3 | FRONT_LOOKS_PLUS), ceiling];
        sort_by_depth(&mut f, C);
        let mut log = Log::default();
        exchange(&f, C, 1.0, SkySeen::uniform(Rgb::ZERO), radiance, &mut log);
        assert_eq!(log.0[0], (1, Rgb::splat(3.0), 1.0));
    }

    /// Facing each other, two surfaces 5e-4 apart are a real gap (fronts facing: they see
    /// each other) or a thin solid (backs facing), whichever their depths say: opposite
    /// facings never join.
    #[test]
    fn opposite_facings_keep_their_order() {
        let up = frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS); // front looks +ω
        let down = frag(5e-4, NO_SIDE, 2); // front looks −ω
        let mut log = Log::default();
        exchange(&[up, down], C, 1.0, SkySeen::uniform(Rgb::splat(7.0)), |t| Rgb::splat(t as f32), &mut log);
        assert_eq!(log.0, vec![(1, Rgb::splat(2.0), 1.0), (2, Rgb::splat(1.0), 1.0)]);
    }

    /// A line grazing the corner where a lit room's wall (front looks −ω) backs onto a dark
    /// room, whose floor (front also looks −ω, another plane) meets the wall there: their
    /// depths agree to far less than the stacked-copy tolerance, but they are not one
    /// surface. The dark floor must see the wall's back, never past it into the lit room.
    #[test]
    fn surfaces_meeting_at_an_edge_are_not_one_layer() {
        let lit_room = frag(-1.0, 9, NO_SIDE | FRONT_LOOKS_PLUS);
        let lit_wall = Fragment { normal: pack_normal(-Vec3::X), ..frag(0.0, NO_SIDE, 1) };
        let dark_floor = Fragment { normal: pack_normal(Vec3::new(0.0, -0.6, -0.8)), ..frag(5e-4, NO_SIDE, 2) };
        let mut log = Log::default();
        exchange(
            &[lit_room, lit_wall, dark_floor],
            C,
            1.0,
            SkySeen::uniform(Rgb::ZERO),
            |t| Rgb::splat((t == 9) as u32 as f32),
            &mut log,
        );
        assert!(
            log.0.iter().all(|&(t, l, _)| t != 2 || l == Rgb::ZERO),
            "the dark floor sees the lit room: {:?}",
            log.0
        );
    }

    /// A layout gives each value's own address (what a prefetch asks for), and none gives none.
    #[test]
    fn texel_layouts_address_their_values() {
        let sums = vec![[0.0f32; 4]; 10];
        let layout = TexelLayout::of(&sums);
        for t in [0u32, 1, 9] {
            assert_eq!(layout.address(t), Some(&sums[t as usize] as *const [f32; 4] as usize));
        }
        assert_eq!(TexelLayout::NONE.address(3), None);
    }

    /// The remembered |n_ω| is the decoded normal's, whatever was asked before: normals that
    /// share a slot, asked in turn and again, and the largest code (the one an empty slot
    /// must not pass for).
    #[test]
    fn remembered_cosines_are_the_decoded_normals() {
        let mut rng = crate::sampling::Rng::new(17, 0);
        // 8 normals in one slot (the slot is a function of the code's halves XORed), and
        // random ones between them.
        let colliding: Vec<u32> = (0..8u32).map(|k| k << 16 | k).collect();
        let mut codes = vec![u32::MAX, 0, u32::MAX];
        for _ in 0..2000 {
            codes.push(colliding[(rng.next_u32() % 8) as usize]);
            codes.push(rng.next_u32());
        }
        for &p in &codes {
            assert_eq!(normal_cos(p).to_bits(), unpack_normal(p).z.abs().to_bits(), "code {p:#x}");
        }
        assert_eq!(normal_cos(u32::MAX), 1.0, "(1, 1) decodes to −ω");
    }

    #[test]
    fn packed_normals_round_trip() {
        let mut rng = crate::sampling::Rng::new(3, 0);
        for _ in 0..1000 {
            let n = crate::sampling::uniform_sphere(rng.next_vec2()).normalize();
            let back = unpack_normal(pack_normal(n));
            assert!(n.cross(back).length() < 1e-4, "{n} → {back}");
        }
        for n in [Vec3::X, -Vec3::Y, Vec3::Z, -Vec3::Z, Vec3::new(1.0, 0.0, -1e-9).normalize()] {
            assert!(n.dot(unpack_normal(pack_normal(n))) >= COPLANAR_COS);
        }
    }

    /// A lamp hanging a centimetre under its ceiling (both fronts look −ω, parallel): within
    /// the reach where layers are looked for, but farther apart than stacked copies, so two
    /// layers. The floor sees the lamp (and the light pass lights it); the ceiling sees the
    /// lamp's single-sided back, black, never the floor past it.
    #[test]
    fn a_lamp_under_its_ceiling_is_a_layer_of_its_own() {
        let floor = frag(0.0, 5, NO_SIDE | FRONT_LOOKS_PLUS);
        let lamp = frag(2.0, NO_SIDE | EMITTER_FLAG, 6);
        let ceiling = frag(2.01, NO_SIDE, 4);
        assert!(ceiling.depth - lamp.depth < C.reach, "the pair must be one the layers are looked for in");
        let frags = [floor, lamp, ceiling];
        let mut log = Log::default();
        emit(&frags, C, 0.25, |t| if t == 6 { Rgb::splat(8.0) } else { Rgb::ZERO }, &mut log);
        assert_eq!(log.0, vec![(5, Rgb::splat(2.0), 0.25)]);
        let mut log = Log::default();
        exchange(&frags, C, 0.5, SkySeen::uniform(Rgb::splat(7.0)), |t| Rgb::splat(t as f32), &mut log);
        // Floor ← lamp (6); lamp ← floor (5); ceiling ← the lamp's back (black).
        assert_eq!(log.0, vec![(5, Rgb::splat(3.0), 0.5), (6, Rgb::splat(2.5), 0.5), (4, Rgb::ZERO, 0.5)]);
    }

    /// An emissive quad (light-pass emitter, emitting along −ω: texel 6) on a ceiling
    /// (texel 4, same facing), at exactly the same depth, over a floor (texel 5): the floor
    /// receives the lamp's emission whichever order the two arrive in, once.
    #[test]
    fn a_lamp_on_its_ceiling_lights_the_floor() {
        let floor = frag(0.0, 5, NO_SIDE | FRONT_LOOKS_PLUS);
        let ceiling = frag(2.0, NO_SIDE, 4);
        let lamp = frag(2.0, NO_SIDE | EMITTER_FLAG, 6);
        for f in orders(&[floor, ceiling, lamp]) {
            let mut log = Log::default();
            emit(&f, C, 0.25, |t| if t == 6 { Rgb::splat(8.0) } else { Rgb::ZERO }, &mut log);
            assert_eq!(log.0, vec![(5, Rgb::splat(2.0), 0.25)], "{f:?}");
        }
    }
}
