//! Special functions the microfacet code needs in double precision.

use std::f64::consts::PI;

pub const SQRT_PI: f64 = 1.772_453_850_905_516;
pub const INV_SQRT_PI: f64 = 0.564_189_583_547_756_3;

#[inline]
pub fn erf(x: f64) -> f64 {
    libm::erf(x)
}

#[inline]
pub fn erfc(x: f64) -> f64 {
    libm::erfc(x)
}

/// Scaled complementary error function erfcx(x) = exp(x²)·erfc(x), accurate
/// for large positive x where erfc underflows (asymptotic series).
pub fn erfcx(x: f64) -> f64 {
    if x < 26.0 {
        // exp(x²) stays finite and erfc keeps its relative precision (no underflow) here.
        return (x * x).exp() * erfc(x);
    }
    // Asymptotic series 1/(x√π)·Σ (−1)ⁿ (2n−1)!!/(2x²)ⁿ: < 1e-16 after 6 terms for x ≥ 26.
    let r = 1.0 / (2.0 * x * x);
    let series = 1.0 - r * (1.0 - 3.0 * r * (1.0 - 5.0 * r * (1.0 - 7.0 * r * (1.0 - 9.0 * r))));
    INV_SQRT_PI / x * series
}

/// Inverse of the standard normal CDF Φ(x) (Acklam's rational approximation,
/// refined by one Halley step on erfc: full double precision).
// Acklam's published coefficients are kept digit for digit.
#[allow(clippy::excessive_precision)]
pub fn norm_inv(p: f64) -> f64 {
    if p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    const A: [f64; 6] =
        [-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02, 1.383577518672690e+02, -3.066479806614716e+01, 2.506628277459239e+00];
    const B: [f64; 5] = [-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02, 6.680131188771972e+01, -1.328068155288572e+01];
    const C: [f64; 6] = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    const D: [f64; 4] = [7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, 3.754408661907416e+00];
    let p_low = 0.02425;
    let x = if p < p_low {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - p_low {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    // Halley refinement; Φ(x) = erfc(-x/√2)/2.
    let e = 0.5 * erfc(-x / std::f64::consts::SQRT_2) - p;
    let u = e * (2.0 * PI).sqrt() * (0.5 * x * x).exp();
    let refined = x - u / (1.0 + 0.5 * x * u);
    if refined.is_finite() {
        refined
    } else {
        x
    }
}

/// Inverse error function on (-1, 1).
pub fn erfinv(y: f64) -> f64 {
    if y <= -1.0 {
        return f64::NEG_INFINITY;
    }
    if y >= 1.0 {
        return f64::INFINITY;
    }
    norm_inv(0.5 * (y + 1.0)) * std::f64::consts::FRAC_1_SQRT_2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfcx_matches_definition_and_asymptotics() {
        for &x in &[0.0f64, 0.5, 2.0, 4.9, 5.1, 10.0, 20.0, 25.9] {
            let direct = (x * x).exp() * erfc(x);
            let v = erfcx(x);
            if x < 20.0 {
                assert!((v - direct).abs() <= 1e-12 * direct, "x={x}: {v} vs {direct}");
            }
            // Asymptotic expansion for large x
            if x >= 20.0 {
                let a = INV_SQRT_PI / x * (1.0 - 0.5 / (x * x) + 0.75 / x.powi(4) - 1.875 / x.powi(6));
                assert!((v - a).abs() <= 1e-7 * a);
            }
        }
    }

    #[test]
    fn norm_inv_inverts_phi() {
        for i in 1..1000 {
            let p = i as f64 / 1000.0;
            let x = norm_inv(p);
            let back = 0.5 * erfc(-x / std::f64::consts::SQRT_2);
            assert!((back - p).abs() < 1e-14, "p={p}");
        }
        for &p in &[1e-300, 1e-20, 1e-10, 1.0 - 1e-12] {
            let x = norm_inv(p);
            let back = 0.5 * erfc(-x / std::f64::consts::SQRT_2);
            assert!(((back - p) / p.min(1.0 - p).max(1e-300)).abs() < 1e-9 || (back - p).abs() < 1e-15);
        }
        for &y in &[-0.999, -0.3, 0.0, 0.7, 0.99999] {
            assert!((erf(erfinv(y)) - y).abs() < 1e-14);
        }
    }
}
