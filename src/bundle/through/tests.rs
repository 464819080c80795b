use glam::Vec3;

use super::*;
use crate::bundle::estimator::{
    Coincidence, EMITTER_FLAG, FRONT_LOOKS_PLUS, emit, exchange, pack_normal, sort_by_depth,
};
use crate::sampling::Rng;

#[derive(Default)]
struct Log(Vec<(u32, Rgb, f32)>);
impl HitSink for Log {
    fn hit(&mut self, t: u32, l: Rgb, a: f32) {
        self.0.push((t, l, a));
    }
}

impl Log {
    fn sorted(mut self) -> Vec<(u32, [u32; 3], u32)> {
        let mut v: Vec<_> =
            self.0.drain(..).map(|(t, l, a)| (t, l.to_array().map(f32::to_bits), a.to_bits())).collect();
        v.sort_unstable();
        v
    }
}

const C: Layering = Coincidence { rounding: 1e-4, stacked: 1e-3, snap: 0.0 }.layering();

fn frag(depth: f32, plus: u32, minus: u32) -> Fragment {
    Fragment { depth, plus, minus, normal: pack_normal(Vec3::Z) }
}

/// Random lines: a few fragments, some at one depth (layers, ties), sides that are target
/// texels, foreign codes or backs, some emitters.
fn random_line(rng: &mut Rng) -> Vec<Fragment> {
    let n = 1 + (rng.next_u32() % 6) as usize;
    let mut frags: Vec<Fragment> = (0..n)
        .map(|_| {
            let depth = (rng.next_u32() % 4) as f32 + if rng.next_f32() < 0.3 { 5e-4 } else { 0.0 };
            let side = |rng: &mut Rng| match rng.next_u32() % 4 {
                0 => NO_SIDE,
                1 => crate::bundle::estimator::FOREIGN + rng.next_u32() % 8,
                _ => rng.next_u32() % 16,
            };
            let plus = side(rng) | if rng.next_f32() < 0.2 { EMITTER_FLAG } else { 0 };
            let minus = side(rng) | if rng.next_f32() < 0.5 { FRONT_LOOKS_PLUS } else { 0 };
            frag(depth, plus, minus)
        })
        .collect();
    sort_by_depth(&mut frags, C);
    frags
}

fn radiance(code: u32) -> Rgb {
    Rgb::new(code as f32 % 7.0, (code % 5) as f32 * 0.5, 1.0 + (code % 3) as f32)
}

/// With every fragment opaque the walk is the exchange and the emission of the estimator,
/// hit for hit.
#[test]
fn opaque_lines_give_exactly_the_estimators_hits() {
    let mut rng = Rng::new(11, 0);
    let sky = SkySeen { ahead: Rgb::new(0.3, 0.6, 0.9), behind: Rgb::new(2.0, 1.0, 0.5) };
    let mut scratch = Vec::new();
    for _ in 0..2000 {
        let frags = random_line(&mut rng);
        let pass = vec![Rgb::ZERO; frags.len()];
        let (mut a, mut b) = (Log::default(), Log::default());
        exchange(&frags, C, 0.25, sky, radiance, &mut a);
        exchange_through(&frags, &pass, C, 0.25, sky, radiance, &mut b, &mut scratch);
        assert_eq!(a.0, b.0, "exchange of {frags:?}");
        let (mut a, mut b) = (Log::default(), Log::default());
        emit(&frags, C, 0.25, radiance, &mut a);
        emit_through(&frags, &pass, C, 0.25, radiance, &mut b, &mut scratch);
        assert_eq!(a.sorted(), b.sorted(), "emit of {frags:?}");
    }
}

/// A floor (texel 1, looks +ω) under a single-sided pane (its top, texel 2, looks +ω; its
/// underside is a back) under the sky: the floor sees the sky through the pane, T·L_sky
/// (the pane's back reflects nothing), the pane's top sees the sky.
#[test]
fn a_floor_under_a_pane_sees_the_sky_times_its_transmittance() {
    let sky = SkySeen::uniform(Rgb::splat(2.0));
    let frags = [frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS), frag(1.0, 2, NO_SIDE | FRONT_LOOKS_PLUS)];
    let mut scratch = Vec::new();
    for (what, t) in [("BLEND α 0.4", Rgb::splat(0.6)), ("tinted transmission", Rgb::new(1.0, 0.5, 0.25))] {
        let mut log = Log::default();
        exchange_through(&frags, &[Rgb::ZERO, t], C, 1.0, sky, |_| Rgb::ZERO, &mut log, &mut scratch);
        assert_eq!(log.0, vec![(1, t * 2.0, 1.0), (2, Rgb::splat(2.0), 1.0)], "{what}");
    }
    // A double-sided pane (underside texel 3, radiance 0.5) adds what it reflects down.
    let frags = [frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS), frag(1.0, 2, 3 | FRONT_LOOKS_PLUS)];
    let mut log = Log::default();
    let seen = |c: u32| if c == 3 { Rgb::splat(0.5) } else { Rgb::ZERO };
    exchange_through(&frags, &[Rgb::ZERO, Rgb::splat(0.6)], C, 1.0, sky, seen, &mut log, &mut scratch);
    assert_eq!(log.0[0], (1, Rgb::splat(0.5 + 0.6 * 2.0), 1.0));
}

/// Two panes and a wall: the running product stops at the wall; what lies beyond it is
/// never seen.
#[test]
fn the_walk_multiplies_front_to_back_and_stops_at_an_opaque_layer() {
    let frags = [
        frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS),
        frag(1.0, NO_SIDE, 10), // pane A, its face toward the floor: radiance of 10
        frag(2.0, NO_SIDE, 11), // pane B
        frag(3.0, NO_SIDE, 12), // wall
        frag(4.0, NO_SIDE, 13), // beyond the wall
    ];
    let pass = [Rgb::ZERO, Rgb::splat(0.5), Rgb::splat(0.25), Rgb::ZERO, Rgb::splat(1.0)];
    let l = |c: u32| Rgb::splat(c as f32);
    let mut log = Log::default();
    exchange_through(&frags, &pass, C, 1.0, SkySeen::uniform(Rgb::splat(100.0)), l, &mut log, &mut Vec::new());
    assert_eq!(log.0[0], (1, Rgb::splat(10.0 + 0.5 * 11.0 + 0.125 * 12.0), 1.0));
}

/// A floor running through a closed box (faces outward, single-sided): buried when the box
/// is opaque, lit through it when the box is glass; a face inside a solid with a pane also
/// inside stays buried.
#[test]
fn buried_looks_past_see_through_layers() {
    let bottom = frag(0.0, NO_SIDE, 8);
    let floor = frag(0.5, 5, NO_SIDE | FRONT_LOOKS_PLUS);
    let top = frag(1.0, 9, NO_SIDE | FRONT_LOOKS_PLUS);
    let sky = SkySeen::uniform(Rgb::splat(4.0));
    let l = |t: u32| Rgb::splat(t as f32);
    let mut scratch = Vec::new();
    let floor_hits = |pass: &[Rgb], frags: &[Fragment], scratch: &mut Vec<Layer>| {
        let mut log = Log::default();
        exchange_through(frags, pass, C, 1.0, sky, l, &mut log, scratch);
        log.0.into_iter().filter(|h| h.0 == 5).collect::<Vec<_>>()
    };
    let opaque = [Rgb::ZERO; 3];
    assert!(floor_hits(&opaque, &[bottom, floor, top], &mut scratch).is_empty());
    let glass = [Rgb::splat(0.5), Rgb::ZERO, Rgb::splat(0.5)];
    assert_eq!(floor_hits(&glass, &[bottom, floor, top], &mut scratch), vec![(5, Rgb::splat(2.0), 1.0)]);
    let pane = frag(0.75, 7, NO_SIDE | FRONT_LOOKS_PLUS);
    let pass = [Rgb::ZERO, Rgb::ZERO, Rgb::splat(0.5), Rgb::ZERO];
    assert!(floor_hits(&pass, &[bottom, floor, pane, top], &mut scratch).is_empty());
}

/// A stacked copy of a pane is the same pane (the layer's T is its members' smallest); a
/// pane stacked on a wall is the wall.
#[test]
fn a_layer_passes_what_its_most_opaque_member_passes() {
    let floor = frag(0.0, 1, NO_SIDE | FRONT_LOOKS_PLUS);
    let pane = frag(1.0, NO_SIDE, NO_SIDE);
    let copy = frag(1.0 + 5e-4, NO_SIDE, NO_SIDE);
    let sky = SkySeen::uniform(Rgb::ONE);
    let mut scratch = Vec::new();
    for (second, want) in [(Rgb::splat(0.6), 0.6), (Rgb::ZERO, 0.0)] {
        let mut log = Log::default();
        let pass = [Rgb::ZERO, Rgb::splat(0.6), second];
        exchange_through(&[floor, pane, copy], &pass, C, 1.0, sky, |_| Rgb::ZERO, &mut log, &mut scratch);
        assert_eq!(log.0, vec![(1, Rgb::splat(want), 1.0)]);
    }
}

/// A lamp (emitting along −ω) over a pane over a floor: the floor receives T·Le, the pane's
/// top the lamp's full emission.
#[test]
fn emitters_light_through_panes() {
    let frags = [
        frag(0.0, 5, NO_SIDE | FRONT_LOOKS_PLUS),
        frag(1.0, 6, NO_SIDE | FRONT_LOOKS_PLUS),
        frag(2.0, NO_SIDE | EMITTER_FLAG, 7),
    ];
    let pass = [Rgb::ZERO, Rgb::new(1.0, 0.5, 0.25), Rgb::ZERO];
    let mut log = Log::default();
    let le = |t: u32| if t == 7 { Rgb::splat(8.0) } else { Rgb::ZERO };
    emit_through(&frags, &pass, C, 0.25, le, &mut log, &mut Vec::new());
    assert_eq!(log.0, vec![(6, Rgb::splat(2.0), 0.25), (5, Rgb::new(2.0, 1.0, 0.5), 0.25)]);
}
