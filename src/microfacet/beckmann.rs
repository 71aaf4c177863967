//! Beckmann specifics: Λ through erfc (no 1 + erf cancellation) and visible
//! slope sampling for incident directions on the whole sphere, inverting the
//! marginal CDF in log space below the horizon (docs/paper-notes.md).

use super::special::{erfc, erfcx, norm_inv, INV_SQRT_PI, SQRT_PI};
use glam::DVec3;

/// Λ for an upward direction with (α tan θ)² = `alpha_tan2`; a = 1/(α tan θ):
/// Λ = (e^{−a²}/(a√π) − erfc(a))/2.
#[inline]
pub fn lambda_up(alpha_tan2: f64) -> f64 {
    if alpha_tan2 <= 0.0 {
        return 0.0;
    }
    if !alpha_tan2.is_finite() {
        return f64::INFINITY;
    }
    let a = 1.0 / alpha_tan2.sqrt();
    if a > 26.0 {
        return 0.0;
    }
    let v = 0.5 * ((-a * a).exp() * INV_SQRT_PI / a - erfc(a));
    v.max(0.0)
}

/// Visible normal (unnormalised) for the stretched unit direction `w`.
#[inline]
pub fn sample_visible_std(w: DVec3, u1: f64, u2: f64) -> Option<DVec3> {
    let sin_theta = (w.x * w.x + w.y * w.y).sqrt();
    let cos_theta = w.z;
    let (cos_phi, sin_phi) = if sin_theta > 0.0 { (w.x / sin_theta, w.y / sin_theta) } else { (1.0, 0.0) };
    let sx = sample_slope_x(cos_theta, sin_theta, u1)?;
    // The y slope is independent: Gaussian with variance 1/2.
    let sy = norm_inv(u2.clamp(1e-300, 1.0 - 1e-16)) * std::f64::consts::FRAC_1_SQRT_2;
    // Rotate back to the azimuth of w.
    let slope_x = cos_phi * sx - sin_phi * sy;
    let slope_y = sin_phi * sx + cos_phi * sy;
    let m = DVec3::new(-slope_x, -slope_y, 1.0);
    if m.is_finite() {
        Some(m)
    } else {
        None
    }
}

/// Samples the visible slope x (α = 1, direction at polar angle θ in the
/// xz-plane): density ∝ (cos θ − x sin θ)·e^{−x²} on x < t = cot θ.
fn sample_slope_x(cos_theta: f64, sin_theta: f64, u: f64) -> Option<f64> {
    let u = u.clamp(1e-12, 1.0 - 1e-12);
    if sin_theta < 1e-7 {
        if cos_theta > 0.0 {
            // Looking straight down at the surface: all normals visible.
            return Some(norm_inv(u) * std::f64::consts::FRAC_1_SQRT_2);
        }
        return None;
    }
    let t = cos_theta / sin_theta;
    if cos_theta >= 0.0 {
        // CDF·A = G(x) = cos θ·erfc(−x)/2 + sin θ·e^{−x²}/(2√π): all terms positive.
        let g = |x: f64| 0.5 * cos_theta * erfc(-x) + 0.5 * INV_SQRT_PI * sin_theta * (-x * x).exp();
        let dg = |x: f64| (cos_theta - x * sin_theta) * (-x * x).exp() * INV_SQRT_PI;
        let hi = t.min(40.0);
        let target = u * g(hi);
        // Initial guess: blend of the exact solutions at θ = 0 (Gaussian) and
        // θ = π/2 (density ∝ −x·e^{−x²}, CDF e^{−x²}).
        let c2 = cos_theta * cos_theta;
        let x0 = c2 * norm_inv(u) * std::f64::consts::FRAC_1_SQRT_2 - (1.0 - c2) * (-u.ln()).sqrt();
        newton_monotone(|x| g(x) - target, dg, x0.min(hi), hi, target)
    } else {
        // Below the horizon x ≤ t < 0 and s = t − x ≥ 0 has density
        // ∝ s·e^{−2|t|s − s²}. Invert in log space:
        // ln G(x) = const − x² + ln(1 + t√π·erfcx(−x)).
        let b = |x: f64| (1.0 + t * SQRT_PI * erfcx(-x)).max(1e-300);
        let lg = |x: f64| -x * x + b(x).ln();
        let dlg = |x: f64| 2.0 * (t - x) / b(x);
        let target = lg(t) + u.ln();
        // Initial guess: Gamma(2, 2|t|) for steep directions, Rayleigh near the horizon.
        let s0 = if t < -1.0 {
            // Solve (1 + λs)e^{−λs} = u approximately: λs ≈ −ln u + ln(1 − ln u).
            let l = -u.ln();
            (l + (1.0 + l).ln()) / (-2.0 * t)
        } else {
            (-u.ln()).sqrt()
        };
        newton_monotone(|x| lg(x) - target, dlg, t - s0, t, 1.0)
    }
}

/// Solves f(x) = 0 for f increasing on (−∞, hi] with f(hi) ≥ 0, by Newton's
/// method from `x0`, safeguarded by bisection once a bracket is known.
/// `scale` sets the tolerance on f.
fn newton_monotone(f: impl Fn(f64) -> f64, df: impl Fn(f64) -> f64, x0: f64, hi: f64, scale: f64) -> Option<f64> {
    let mut lo = f64::NEG_INFINITY;
    let mut hi = hi;
    let mut x = if x0.is_finite() && x0 < hi { x0 } else { hi - 1.0 };
    for _ in 0..100 {
        let fx = f(x);
        if fx.abs() <= 1e-14 * scale {
            return Some(x);
        }
        if fx > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        let mut next = x - fx / df(x);
        if !(next > lo && next < hi && next.is_finite()) {
            next = if lo.is_finite() { 0.5 * (lo + hi) } else { x - (1.0 + x.abs()) };
        }
        if (next - x).abs() <= 1e-13 * (1.0 + x.abs()) {
            return Some(next);
        }
        x = next;
    }
    x.is_finite().then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slope_sampling_inverts_the_cdf() {
        // The sampled slope's CDF value must equal u (exact inversion), above and below the horizon.
        for &theta in &[0.3f64, 1.0, 1.5, 1.6, 2.2, 2.9, 3.1] {
            let (c, s) = (theta.cos(), theta.sin());
            let t = c / s;
            for i in 1..50 {
                let u = i as f64 / 50.0;
                let x = sample_slope_x(c, s, u).unwrap();
                assert!(x <= t + 1e-12);
                // CDF by numerical quadrature of (c − y s) e^{−y²} on (−∞, x] over (−∞, t].
                let integ = |a: f64, b: f64| {
                    let n = 40000;
                    let h = (b - a) / n as f64;
                    (0..n)
                        .map(|k| {
                            let y = a + (k as f64 + 0.5) * h;
                            (c - y * s) * (-y * y).exp()
                        })
                        .sum::<f64>()
                        * h
                };
                let lo = if t < 0.0 { t - 14.0 / (1.0 + t.abs()) } else { -12.0 };
                let cdf = integ(lo, x) / integ(lo, t);
                assert!((cdf - u).abs() < 1e-6, "theta={theta} u={u}: cdf {cdf}");
            }
        }
    }
}
