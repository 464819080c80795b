//! Closed-form answers for the analytic test scenes (furnace, sky, point and polygon
//! lights), shared by every test and benchmark that checks an estimator against them.

use glam::{DVec3, Vec3};

use crate::scene::Rgb;

/// Irradiance at `p` (unit normal `n`) from a Lambertian polygon of radiance `le` entirely
/// above p's horizon and unoccluded (Lambert's formula):
/// E = (Le/2)·|Σ γᵢ n·(Rᵢ × Rᵢ₊₁)/|Rᵢ × Rᵢ₊₁||, Rᵢ the unit vectors to the vertices and
/// γᵢ the angle between consecutive ones. Computed in f64.
pub fn polygon_irradiance(p: Vec3, n: Vec3, poly: &[Vec3], le: Rgb) -> Rgb {
    let (p, n) = (p.as_dvec3(), n.as_dvec3());
    let r: Vec<DVec3> = poly.iter().map(|v| (v.as_dvec3() - p).normalize()).collect();
    let mut sum = 0.0;
    for i in 0..r.len() {
        let (a, b) = (r[i], r[(i + 1) % r.len()]);
        let c = a.cross(b);
        let gamma = a.dot(b).clamp(-1.0, 1.0).acos();
        sum += gamma * n.dot(c / c.length());
    }
    le * (0.5 * sum.abs()) as f32
}

/// Irradiance inside a closed furnace: every surface has albedo ρ and emits Le, so the
/// radiance everywhere is Le/(1−ρ) and E = π·Le/(1−ρ).
pub fn furnace_irradiance(le: Rgb, albedo: f32) -> Rgb {
    le * (std::f32::consts::PI / (1.0 - albedo))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_huge_polygon_overhead_gives_pi_le() {
        // A 2·10⁴ m square 1 m above the point fills the hemisphere: E → π·Le.
        let s = 1e4;
        let poly = [Vec3::new(-s, 1.0, -s), Vec3::new(s, 1.0, -s), Vec3::new(s, 1.0, s), Vec3::new(-s, 1.0, s)];
        let e = polygon_irradiance(Vec3::ZERO, Vec3::Y, &poly, Rgb::ONE);
        assert!((e.x - std::f32::consts::PI).abs() < 1e-3, "{e}");
    }

    #[test]
    fn a_small_distant_polygon_follows_the_inverse_square_law() {
        // Area A at distance d straight overhead: E ≈ Le·A/d² (cosines 1).
        let (h, d) = (0.01f32, 10.0f32);
        let poly = [Vec3::new(-h, d, -h), Vec3::new(h, d, -h), Vec3::new(h, d, h), Vec3::new(-h, d, h)];
        let e = polygon_irradiance(Vec3::ZERO, Vec3::Y, &poly, Rgb::ONE).x;
        let approx = (2.0 * h) * (2.0 * h) / (d * d);
        assert!((e / approx - 1.0).abs() < 1e-4, "{e} vs {approx}");
    }
}
