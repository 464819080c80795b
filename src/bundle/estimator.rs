//! The radiance exchange along one bundle ray (docs/ARCHITECTURE.md "Units and the estimator").
//!
//! A pixel's fragments, ordered by depth along ω, are the surfaces one bundle line crosses.
//! Between two consecutive fragments, each sees the other: the side of fragment i that looks
//! along +ω sees the side of fragment i+1 that looks along −ω, and vice versa; the first and
//! last sides see the sky. A side that is not a lit face (the back of a single-sided surface:
//! the inside of closed geometry) is black and receives nothing — that is what stops leaks.
//!
//! A side is coded in 31 bits: a texel of the bake's target (below [`FOREIGN`]), a lit face
//! outside the target (`FOREIGN + k`, k naming the fragment's triangle for whoever resolves
//! it: its radiance is looked up, it receives nothing), or [`NO_SIDE`].
//!
//! Every hit on a target texel adds `a_px · L_seen` and `a_px` to it; its irradiance is then
//! the self-normalising `E = π · Σ a·L / Σ a` (hits are cosine-distributed because a texel's
//! projected area is ∝ |n·ω|).
//!
//! The light pass uses the same ordering but only emitter fragments give: the neighbour
//! facing an emitting side receives `a_px · Le`, normalised later by the texel's area.
//!
//! These functions are the spec the GPU resolve shader is held equal to.

use crate::scene::Rgb;

/// "No texel": the side is not a lit face.
pub const NO_SIDE: u32 = 0x7FFF_FFFF;
/// Codes from here up to [`NO_SIDE`] are foreign sides: `FOREIGN + k`.
pub const FOREIGN: u32 = 0x4000_0000;
/// Set on `plus` of fragments that belong to the emitter group of a light pass.
pub const EMITTER_FLAG: u32 = 0x8000_0000;
/// Set on `minus` when the triangle's front face looks along +ω.
pub const FRONT_LOOKS_PLUS: u32 = 0x8000_0000;
const CODE_MASK: u32 = 0x7FFF_FFFF;

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

/// Whether `a` lies before `b` along ω. Depths within `eps` are one place: back-to-back
/// coincident surfaces (two rooms sharing a zero-thickness wall, each room's wall facing
/// into it) must be ordered by facing, or rounding could put the far room's wall first and
/// let the rooms see each other through the wall. The surface whose front looks back along
/// −ω goes first; its room lies before it.
#[inline]
fn before(a: &Fragment, b: &Fragment, eps: f32) -> bool {
    if (a.depth - b.depth).abs() <= eps { a.coincident_rank() < b.coincident_rank() } else { a.depth < b.depth }
}

/// Sorts one pixel's fragments along ω (see [`before`]; `eps` is the depth tolerance of
/// coincident surfaces). Insertion sort: lists are short (a few surfaces) and it is stable,
/// so ties keep their deterministic build order.
#[inline]
pub fn sort_by_depth(frags: &mut [Fragment], eps: f32) {
    for i in 1..frags.len() {
        let f = frags[i];
        let mut j = i;
        while j > 0 && before(&f, &frags[j - 1], eps) {
            frags[j] = frags[j - 1];
            j -= 1;
        }
        frags[j] = f;
    }
}

/// Receives hits. `texel` is a lit face's texel.
pub trait HitSink {
    fn hit(&mut self, texel: u32, weighted_radiance: Rgb, weight: f32);
}

/// Global-bundle exchange over one pixel's depth-sorted fragments: every target side
/// receives the radiance of what it sees. `seen(code)` is the outgoing radiance toward the
/// bundle of the side with that code (target texel or foreign; never called for
/// [`NO_SIDE`], which is black).
#[inline]
pub fn exchange(frags: &[Fragment], a_px: f32, sky: Rgb, mut seen: impl FnMut(u32) -> Rgb, sink: &mut impl HitSink) {
    let mut look = |side: u32| {
        let code = side & CODE_MASK;
        if code == NO_SIDE { Rgb::ZERO } else { seen(code) }
    };
    let m = frags.len();
    for i in 0..m {
        let f = &frags[i];
        if let Some(t) = f.plus_texel() {
            let l = if i + 1 < m { look(frags[i + 1].minus) } else { sky };
            sink.hit(t, l * a_px, a_px);
        }
        if let Some(t) = f.minus_texel() {
            let l = if i > 0 { look(frags[i - 1].plus) } else { sky };
            sink.hit(t, l * a_px, a_px);
        }
    }
}

/// Light-pass exchange: each emitter fragment's emitting side lights the target side of the
/// neighbour facing it. `emission(code)` is the emitted radiance of the side with that code
/// (zero if it does not emit).
#[inline]
pub fn emit(frags: &[Fragment], a_px: f32, mut emission: impl FnMut(u32) -> Rgb, sink: &mut impl HitSink) {
    let m = frags.len();
    for i in 0..m {
        let f = &frags[i];
        if !f.is_emitter() {
            continue;
        }
        let (plus, minus) = (f.plus & CODE_MASK, f.minus & CODE_MASK);
        if let (true, Some(next)) = (plus != NO_SIDE, frags.get(i + 1))
            && let Some(dst) = next.minus_texel()
        {
            sink.hit(dst, emission(plus) * a_px, a_px);
        }
        if let (true, Some(prev)) = (minus != NO_SIDE, i.checked_sub(1).map(|j| &frags[j]))
            && let Some(dst) = prev.plus_texel()
        {
            sink.hit(dst, emission(minus) * a_px, a_px);
        }
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

    fn frag(depth: f32, plus: u32, minus: u32) -> Fragment {
        Fragment { depth, plus, minus }
    }

    #[test]
    fn sorting_is_stable_by_depth() {
        let mut f = vec![frag(3.0, 1, 1), frag(1.0, 2, 2), frag(3.0, 3, 3), frag(-1.0, 4, 4)];
        sort_by_depth(&mut f, 0.0);
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
            sort_by_depth(&mut f, 1e-4);
            assert_eq!(f[1], a_wall);
            let mut log = Log::default();
            // Room A's texels (1, 3) glow; room B's (2, 4) must see nothing of them.
            exchange(&f, 1.0, Rgb::ZERO, |t| if t == 1 || t == 3 { Rgb::ONE } else { Rgb::ZERO }, &mut log);
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
        exchange(&frags, 0.5, Rgb::splat(7.0), source, &mut log);
        assert_eq!(log.0, vec![(10, Rgb::splat(10.0), 0.5), (20, Rgb::splat(5.0), 0.5)]);
    }

    /// A lit side looking at the back of a single-sided surface sees black; the outermost
    /// sides see the sky.
    #[test]
    fn sky_at_the_ends_and_black_from_single_sided_backs() {
        // A double-sided panel (texels 1 and 2) in front of a wall seen from behind.
        let frags = [frag(0.0, 1, 2), frag(1.0, 3, NO_SIDE)];
        let mut log = Log::default();
        exchange(&frags, 1.0, Rgb::splat(4.0), |t| Rgb::splat(t as f32 * 100.0), &mut log);
        assert_eq!(log.0, vec![(1, Rgb::ZERO, 1.0), (2, Rgb::splat(4.0), 1.0), (3, Rgb::splat(4.0), 1.0)]);
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
        emit(&frags, 0.25, |t| if t == 6 { Rgb::splat(8.0) } else { Rgb::ZERO }, &mut log);
        assert_eq!(log.0, vec![(5, Rgb::splat(2.0), 0.25)]);
    }
}
