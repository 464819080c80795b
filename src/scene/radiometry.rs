//! The brightest light a scene may carry: emission, sky and punctual lights whose products
//! in the estimator's f32 sums cannot overflow, derived from the scene's surface area.
//!
//! # The bound
//!
//! A bake's largest sums are the global bundles' weighted totals of each texel
//! ([`crate::bundle::progressive`]), `Σ_b w_b Σ_hits a·L` with `w_b = (b+1)²`:
//! * in one direction the bundle pixels that land on a texel cover at most its surface's
//!   projected area and a rim of pixels around it, so `Σ a ≤ 2A` (A: the scene's surface
//!   area); a batch of `d` directions gives `≤ 2A·d`;
//! * over `B` batches `Σ w_b ≤ B³`;
//! * the radiance `L` a hit reads gains at most one bounce a batch (albedo ≤ 1, which the
//!   loader enforces): `L ≤ (B+1)·(5·L₀ + E_p/π)`, with `L₀` the largest emission or sky
//!   radiance, `4π·L₀` the most the light pass can estimate (`2π/N·Σ a·Le/A_texel` with
//!   `Σ a ≤ 2·A_texel` a direction), and `E_p` the punctual lights' irradiance.
//!
//! With `d·B = D` directions and `B + 1 ≤ 2B`, the totals stay below `4·A·D·B³·(5·L₀ +
//! E_p/π)`. At the most any bake takes, `D = 2²⁰` ([`MOST_DIRECTIONS`]) in batches of 2 (`B
//! = 2¹⁹`, [`MOST_BATCHES`]), that is `2⁷⁹·A·(5·L₀ + E_p/π)`, held below half of `f32::MAX`
//! (room for the π and the rounding): `5·L₀ + E_p/π ≤ R = f32::MAX / (2⁸⁰·A)`. The budget is
//! split in halves: emission and sky get `L₀ ≤ R/10`, the punctual lights `E_p ≤ π·R/2`
//! between them, `1/n` each. A directional light's `E_p` is its intensity; a point or spot
//! light's is `I/d²`, bounded here at `d = `[`NEAREST_LIGHT`] (a surface nearer than that to
//! a bright lamp can still overflow: every output is checked for non-finite values and a
//! bake that has them fails).
//!
//! For a 100 m² room that allows emission up to 2.8·10¹¹ W/(sr·m²), a sun of 4.4·10¹² W/m²
//! and a point light of 4.4·10⁸ W/sr; for a 1 km² map 2.8·10⁷, 4.4·10⁸ and 4.4·10⁴. The
//! weights alone (`Σ w·Σ a ≤ 2⁷⁹·A`) need `A ≤ f32::MAX / 2⁸⁰ ≈ 2.8·10¹⁴ m²`.

/// Most bundle directions any bake takes (`bake::MAX_SAMPLES`; a test there holds them equal).
pub const MOST_DIRECTIONS: f64 = (1u64 << 20) as f64;
/// Most batches of a bake: [`MOST_DIRECTIONS`] in batches of the fewest directions a batch
/// has (`bundle::MIN_BATCH_SIZE`, 2).
pub const MOST_BATCHES: f64 = (1u64 << 19) as f64;
/// Distance from a point or spot light at which its irradiance is bounded, metres.
pub const NEAREST_LIGHT: f64 = 0.01;

/// The bounds of one scene, from its surface area.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightCeiling {
    /// The scene's surface area, m².
    pub area: f64,
    /// `R`: the radiance budget of the module documentation, W/(sr·m²).
    budget: f64,
}

impl LightCeiling {
    /// The ceiling of a scene whose triangles cover `area` m².
    pub fn for_area(area: f64) -> LightCeiling {
        let factor = 4.0 * MOST_DIRECTIONS * MOST_BATCHES.powi(3) * 2.0;
        LightCeiling { area, budget: f32::MAX as f64 / (factor * area.max(f64::MIN_POSITIVE)) }
    }

    /// The largest surface area whose sums stay finite, m².
    pub fn most_area() -> f64 {
        f32::MAX as f64 / (4.0 * MOST_DIRECTIONS * MOST_BATCHES.powi(3) * 2.0)
    }

    /// Whether the scene's area itself keeps the weights finite.
    pub fn area_fits(&self) -> bool {
        self.area.is_finite() && self.area <= Self::most_area()
    }

    /// Most emission or sky radiance, W/(sr·m²).
    pub fn radiance(&self) -> f64 {
        self.budget / 10.0
    }

    /// Most intensity of each of `lights` punctual lights: irradiance for a directional light
    /// (W/m²), radiant intensity for a point or spot light (W/sr).
    pub fn light_intensity(&self, directional: bool, lights: usize) -> f64 {
        let irradiance = std::f64::consts::PI * self.budget / 2.0 / lights.max(1) as f64;
        if directional { irradiance } else { irradiance * NEAREST_LIGHT * NEAREST_LIGHT }
    }
}

/// A light value above the scene's ceiling.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error(
    "{what} {:e} {unit} is more than the {most:.2e} {unit} whose light the estimator's f32 sums can hold in this scene \
     ({area:.3e} m² of surface)",
    *value as f32
)]
pub struct TooBright {
    pub what: String,
    pub value: f64,
    pub most: f64,
    pub unit: &'static str,
    pub area: f64,
}

impl LightCeiling {
    /// `Ok` when `value` (what: `what`, in `unit`) is at most `most`.
    pub fn check(
        &self,
        what: impl FnOnce() -> String,
        value: f64,
        most: f64,
        unit: &'static str,
    ) -> Result<(), TooBright> {
        if value <= most {
            return Ok(());
        }
        Err(TooBright { what: what(), value, most, unit, area: self.area })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_documented_figures_follow_from_the_formula() {
        let room = LightCeiling::for_area(100.0);
        assert!((room.radiance() / 2.8e11 - 1.0).abs() < 0.02, "{}", room.radiance());
        assert!((room.light_intensity(true, 1) / 4.4e12 - 1.0).abs() < 0.02);
        assert!((room.light_intensity(false, 1) / 4.4e8 - 1.0).abs() < 0.02);
        let map = LightCeiling::for_area(1e6);
        assert!((map.radiance() / 2.8e7 - 1.0).abs() < 0.02);
        assert!((LightCeiling::most_area() / 2.8e14 - 1.0).abs() < 0.02, "{}", LightCeiling::most_area());
        // Many lights share the punctual half.
        assert_eq!(room.light_intensity(true, 4), room.light_intensity(true, 1) / 4.0);
    }

    /// The bound holds the worst case it is derived for: the totals of a texel that sees
    /// the brightest allowed light through every hit, at the most directions and batches.
    #[test]
    fn the_worst_case_totals_stay_finite() {
        for area in [1e-6, 1.0, 100.0, 1e6, LightCeiling::most_area()] {
            let c = LightCeiling::for_area(area);
            let b = MOST_BATCHES as f32;
            let radiance =
                (b + 1.0) * (5.0 * c.radiance() as f32 + c.light_intensity(true, 1) as f32 / std::f32::consts::PI);
            let hits = 2.0 * area as f32 * (MOST_DIRECTIONS / MOST_BATCHES) as f32;
            let weights = b * b * b;
            let total = weights * hits * radiance * std::f32::consts::PI;
            assert!(total.is_finite() && radiance.is_finite(), "area {area}: {total}");
        }
    }
}
