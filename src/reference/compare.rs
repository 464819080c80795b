//! Comparing estimates with the reference: the error figure every convergence test and
//! benchmark quotes.

use glam::DVec3;

/// Relative RMS error of estimates against a noisy reference, over all points and
/// channels: `sqrt(max(Σ(got − want)² − Σσ², 0) / Σ want²)`. Subtracting the reference's
/// variance σ² removes its own noise in quadrature (E[(got − want)²] = error² + σ² for an
/// independent reference), so the figure measures the estimate, not the reference.
#[derive(Clone, Copy, Debug, Default)]
pub struct RelativeRmsError {
    squared_error: f64,
    squared_reference: f64,
    reference_variance: f64,
}

impl RelativeRmsError {
    /// Adds one point: the estimate, the reference value and the reference's standard error.
    pub fn add(&mut self, got: DVec3, want: DVec3, stderr: DVec3) {
        self.squared_error += (got - want).length_squared();
        self.squared_reference += want.length_squared();
        self.reference_variance += stderr.length_squared();
    }

    /// The error so far (0 when the reference is all zero).
    pub fn value(&self) -> f64 {
        if self.squared_reference > 0.0 {
            ((self.squared_error - self.reference_variance).max(0.0) / self.squared_reference).sqrt()
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ten_percent_high_everywhere_is_ten_percent() {
        let mut e = RelativeRmsError::default();
        for k in 1..5 {
            let want = DVec3::new(k as f64, 2.0 * k as f64, 0.5);
            e.add(want * 1.1, want, DVec3::ZERO);
        }
        assert!((e.value() - 0.1).abs() < 1e-12, "{}", e.value());
    }

    #[test]
    fn reference_noise_is_removed_in_quadrature() {
        // Errors of 0.5 per channel against σ = 0.3: what is left is √(0.5² − 0.3²) = 0.4.
        let mut e = RelativeRmsError::default();
        e.add(DVec3::splat(1.5), DVec3::splat(1.0), DVec3::splat(0.3));
        assert!((e.value() - 0.4).abs() < 1e-12, "{}", e.value());
        // An exact estimate of a noisy reference scores 0, not σ.
        let mut exact = RelativeRmsError::default();
        exact.add(DVec3::ONE, DVec3::ONE, DVec3::splat(0.1));
        assert_eq!(exact.value(), 0.0);
    }
}
