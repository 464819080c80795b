//! The source radiance of the texels outside a region shard's share, in half floats. From
//! round 2 a round's source (the last round's light reflected) is dense, and a region
//! shard holds it for every texel of the LOD but its own (the rest of the scene, as its
//! bundles see it): in f32 that was 12 B a texel, a whole LOD's worth in every shard and the
//! largest thing a shard held beyond its share. In three half floats it is 6 B.
//!
//! What it costs: each such value is rounded to nearest, relative 2⁻¹¹ (0.05 %) at most,
//! far below the noise of any bake (a few % at hundreds of directions), so a texel's
//! irradiance from round 2 differs from the single bake's by at most that share of what
//! the other shares' texels send it (`tests/region_shards.rs`). Radiance is scaled by a
//! power of two set by the LOD's brightest value, which lands between 2¹⁴ and 2¹⁵, under
//! half floats' largest (no overflow, whatever the scene's units); a value loses its
//! relative precision only below 2⁻²⁸ of the brightest (it is then kept to 2⁻³⁹ of the
//! brightest). Within 2⁻¹² of f32's largest value, rounding up reaches infinity, as any
//! rounding to fewer bits would.

use half::f16;

use crate::scene::Rgb;

/// A colour in half floats (bits), under a [`HalfScale`].
pub type HalfRgb = [u16; 3];

/// The power of two `2^exp` a source is divided by before its values are held in half
/// floats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HalfScale {
    exp: i32,
}

/// The scale's exponent keeps the brightest value's scaled magnitude in `[2^14, 2^15)`,
/// below half floats' largest (65504), within these bounds: both `2^exp` and `2^−exp` are
/// normal f32, and a half float's smallest step times `2^exp` (`2^(exp − 24)`) is one too,
/// so that undoing the scale is exact.
const EXP_RANGE: (i32, i32) = (-100, 113);

/// `2^e` for a normal f32 exponent.
fn pow2(e: i32) -> f32 {
    debug_assert!((-126..=127).contains(&e));
    f32::from_bits(((e + 127) as u32) << 23)
}

impl HalfScale {
    /// The scale for `values`: from their largest finite magnitude (none or all zero: 1).
    pub fn of(values: &[Rgb]) -> Self {
        let largest =
            values.iter().flat_map(|v| v.to_array()).map(f32::abs).filter(|x| x.is_finite()).fold(0.0f32, f32::max);
        if largest == 0.0 {
            return HalfScale { exp: 0 };
        }
        // ⌊log2⌋ from the exponent bits; a subnormal is below 2^−126.
        let biased = (largest.to_bits() >> 23) as i32;
        let log2 = if biased == 0 { -127 } else { biased - 127 };
        HalfScale { exp: (log2 - 14).clamp(EXP_RANGE.0, EXP_RANGE.1) }
    }

    /// `v` in half floats.
    #[inline]
    pub fn encode(self, v: Rgb) -> HalfRgb {
        let down = pow2(-self.exp);
        v.to_array().map(|c| f16::from_f32(c * down).to_bits())
    }

    /// The colour `h` holds (exactly: a half float times a power of two is an f32).
    #[inline]
    pub fn decode(self, h: HalfRgb) -> Rgb {
        let up = pow2(self.exp);
        let [r, g, b] = h.map(|c| f16::from_bits(c).to_f32() * up);
        Rgb::new(r, g, b)
    }

    /// `v` as half floats hold it.
    #[inline]
    pub fn round(self, v: Rgb) -> Rgb {
        self.decode(self.encode(v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every finite half float survives decoding and encoding again, at scales from the
    /// smallest to the largest: what is held is read back as it was rounded, and rounding
    /// twice is rounding once.
    #[test]
    fn a_rounded_value_is_held_exactly() {
        for exp in [EXP_RANGE.0, -40, -14, 0, 17, EXP_RANGE.1] {
            let scale = HalfScale { exp };
            for bits in 0..=u16::MAX {
                if !f16::from_bits(bits).is_finite() {
                    continue;
                }
                let h = [bits, bits ^ 0x8000, 0x3c00];
                let v = scale.decode(h);
                if !v.is_finite() {
                    // Past f32's largest: only at the largest scale, for half floats above
                    // any f32 but what rounds up from within 2⁻¹² of f32's largest.
                    let past = f16::from_bits(bits).to_f32().abs() >= 32768.0;
                    assert!(exp == EXP_RANGE.1 && past, "exp {exp}, bits {bits:#06x}");
                    continue;
                }
                assert_eq!(scale.encode(v), h, "exp {exp}, bits {bits:#06x}");
                assert_eq!(scale.round(v), v);
            }
        }
    }

    /// The rounding error is within half a step of half floats: relative 2⁻¹¹, or 2⁻²⁵ of
    /// `2^exp` (at most 2⁻³⁹ of the brightest value) below half floats' normal range; the
    /// brightest value never overflows. Over values of 40 binary orders of magnitude,
    /// brightest values from 10⁻²⁰ to f32's largest.
    #[test]
    fn rounding_is_to_half_a_step() {
        let mut rng = crate::sampling::Rng::new(11, 3);
        // Just under powers of two too, where rounding up could carry past the largest.
        let under = |x: f32| f32::from_bits(x.to_bits() - 1);
        for brightest in [1e-20f32, 3e-7, 1.0, under(1.0), 0.7, under(2.0), 65504.0, under(65536.0), 1e6, 3.4e38] {
            let mut values: Vec<Rgb> = (0..4000)
                .map(|_| {
                    let mut c = || brightest * (2f32).powf(-40.0 * rng.next_f32()) * rng.next_f32();
                    Rgb::new(c(), c(), c())
                })
                .collect();
            values.push(Rgb::new(brightest, 0.0, brightest * 0.5));
            let exact = values.clone();
            let scale = HalfScale::of(&exact);
            for v in &mut values {
                *v = scale.round(*v);
            }
            let floor = (-25f64).exp2() * (scale.exp as f64).exp2();
            assert!(floor <= (-39f64).exp2() * brightest as f64, "brightest {brightest}, exp {}", scale.exp);
            for (r, e) in values.iter().zip(&exact) {
                for (r, e) in r.to_array().into_iter().zip(e.to_array()) {
                    let bound = ((-11f64).exp2() * e as f64).max(floor);
                    assert!(r.is_finite(), "{e} overflowed");
                    assert!((r as f64 - e as f64).abs() <= bound, "{e} held as {r} (bound {bound:e})");
                }
            }
        }
        // Nothing to scale: nothing changes.
        assert_eq!(HalfScale::of(&[Rgb::ZERO; 3]), HalfScale { exp: 0 });
        assert_eq!(HalfScale { exp: 0 }.round(Rgb::ZERO), Rgb::ZERO);
    }
}
