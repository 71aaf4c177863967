//! Fresnel reflectance: conductors with a complex index of refraction η + ik
//! (per channel), and real dielectrics.

/// Unpolarised Fresnel reflectance of a conductor with relative complex IOR
/// η + ik at an incidence cosine `cos_i` (> 0). Exact (not Schlick): the
/// classic closed form in terms of a² + b² with (a + ib)² = η̃² − sin²θ,
///
/// R_s = (t1 − t2)/(t1 + t2),  R_p = R_s·(t3 − t4)/(t3 + t4),
///
/// averaged as (R_s + R_p)/2 = (t1 − t2)·t3 / ((t1 + t2)(t3 + t4)): one
/// division instead of two (the function runs per channel at every vertex of
/// the random walks).
#[inline]
pub fn conductor(cos_i: f64, eta: f64, k: f64) -> f64 {
    let c2 = (cos_i * cos_i).min(1.0);
    let s2 = 1.0 - c2;
    let t = eta * eta - k * k - s2;
    let a2b2 = (t * t + 4.0 * eta * eta * k * k).max(0.0).sqrt();
    let a = (0.5 * (a2b2 + t)).max(0.0).sqrt();
    let t1 = a2b2 + c2;
    let t2 = 2.0 * cos_i * a;
    let t3 = a2b2 * c2 + s2 * s2;
    let t4 = t2 * s2;
    let f = (t1 - t2) * t3 / ((t1 + t2) * (t3 + t4));
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// [`conductor`] for four channels at one incidence cosine. On x86-64 the
/// channels go two by two through SSE2 (part of the x86-64 baseline): the two
/// square roots and the division dominate the cost of a walk vertex, and a
/// packed square root or division costs what a scalar one does. Every lane
/// performs the operations of [`conductor`] in the same order, so the results
/// are bit-identical to it.
#[inline]
pub fn conductor4(cos_i: f64, eta: &[f64; 4], k: &[f64; 4]) -> [f64; 4] {
    #[cfg(target_arch = "x86_64")]
    let f = {
        use std::arch::x86_64::*;
        let c2 = (cos_i * cos_i).min(1.0);
        let s2 = 1.0 - c2;
        let mut f = [0.0f64; 4];
        // SAFETY: SSE2 is enabled on every x86-64 target; the loads and
        // stores read and write two f64 inside arrays of four.
        unsafe {
            let (vc2, vs2, vci) = (_mm_set1_pd(c2), _mm_set1_pd(s2), _mm_set1_pd(cos_i));
            let (zero, half, two, four) = (_mm_setzero_pd(), _mm_set1_pd(0.5), _mm_set1_pd(2.0), _mm_set1_pd(4.0));
            for h in [0, 2] {
                let e = _mm_loadu_pd(eta.as_ptr().add(h));
                let kk = _mm_loadu_pd(k.as_ptr().add(h));
                let t = _mm_sub_pd(_mm_sub_pd(_mm_mul_pd(e, e), _mm_mul_pd(kk, kk)), vs2);
                let q = _mm_add_pd(_mm_mul_pd(t, t), _mm_mul_pd(_mm_mul_pd(_mm_mul_pd(_mm_mul_pd(four, e), e), kk), kk));
                // max(x, 0) returns 0 for a NaN x, as f64::max does.
                let a2b2 = _mm_sqrt_pd(_mm_max_pd(q, zero));
                let a = _mm_sqrt_pd(_mm_max_pd(_mm_mul_pd(half, _mm_add_pd(a2b2, t)), zero));
                let t1 = _mm_add_pd(a2b2, vc2);
                let t2 = _mm_mul_pd(_mm_mul_pd(two, vci), a);
                let t3 = _mm_add_pd(_mm_mul_pd(a2b2, vc2), _mm_mul_pd(vs2, vs2));
                let t4 = _mm_mul_pd(t2, vs2);
                let num = _mm_mul_pd(_mm_sub_pd(t1, t2), t3);
                let den = _mm_mul_pd(_mm_add_pd(t1, t2), _mm_add_pd(t3, t4));
                _mm_storeu_pd(f.as_mut_ptr().add(h), _mm_div_pd(num, den));
            }
        }
        f.map(|f| if f.is_finite() { f.clamp(0.0, 1.0) } else { 1.0 })
    };
    #[cfg(not(target_arch = "x86_64"))]
    let f = std::array::from_fn(|c| conductor(cos_i, eta[c], k[c]));
    f
}

/// Unpolarised Fresnel reflectance of a dielectric interface with relative IOR
/// `eta` = η_t/η_i, for incidence cosine `cos_i` (taken in absolute value).
/// Returns 1 under total internal reflection. The same function as
/// [`dielectric_full`] seen from the incident side, in the arithmetic of the
/// random walks of Heitz 2016 and Cui 2023 (src/microfacet/dielectric.rs
/// explains why both stay).
#[inline]
pub fn dielectric(cos_i: f64, eta: f64) -> f64 {
    let ci = cos_i.abs().min(1.0);
    let s2t = (1.0 - ci * ci) / (eta * eta);
    if s2t >= 1.0 {
        return 1.0;
    }
    let ct = (1.0 - s2t).sqrt();
    let rs = (ci - eta * ct) / (ci + eta * ct);
    let rp = (eta * ci - ct) / (eta * ci + ct);
    0.5 * (rs * rs + rp * rp)
}

/// Dielectric Fresnel with the conventions of Mitsuba 3's `fresnel()`:
/// `eta` = η_int/η_ext of the interface and the sign
/// of `cos_i` (measured against the normal that points to the exterior) tells
/// the side. Returns (F, cos θ_t, η_it, η_ti): cos θ_t carries the sign opposite
/// to `cos_i` (0 under total internal reflection, where F = 1), η_it is the
/// relative IOR in the direction of travel and η_ti = 1/η_it. Index-matched
/// (η = 1) gives F = 0; exactly grazing incidence gives F = 1.
#[inline]
pub fn dielectric_full(cos_i: f64, eta: f64) -> (f64, f64, f64, f64) {
    let outside = cos_i >= 0.0;
    let rcp = 1.0 / eta;
    let (eta_it, eta_ti) = if outside { (eta, rcp) } else { (rcp, eta) };
    let cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti;
    let ci = cos_i.abs();
    let ct = cos_t2.max(0.0).sqrt();
    let f = if eta == 1.0 {
        0.0
    } else if ci == 0.0 {
        1.0
    } else {
        let a_s = (ci - eta_it * ct) / (ci + eta_it * ct);
        let a_p = (ct - eta_it * ci) / (ct + eta_it * ci);
        0.5 * (a_s * a_s + a_p * a_p)
    };
    // Mitsuba's mulsign_neg: the sign bit of cos_i decides (−0 counts as negative).
    let cos_t = if cos_i.is_sign_negative() { ct } else { -ct };
    (f, cos_t, eta_it, eta_ti)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_mirror_and_normal_incidence() {
        // η = 0, k = 1 (Mitsuba's material "none") is a perfect mirror.
        for &c in &[1.0, 0.7, 0.2, 1e-3] {
            assert!((conductor(c, 0.0, 1.0) - 1.0).abs() < 1e-12);
        }
        // Normal incidence: |(ñ − 1)/(ñ + 1)|².
        let (n, k) = (0.27, 3.4);
        let r0 = ((n - 1.0) * (n - 1.0) + k * k) / ((n + 1.0) * (n + 1.0) + k * k);
        assert!((conductor(1.0, n, k) - r0).abs() < 1e-12);
        // A dielectric is the k = 0 conductor.
        for &c in &[1.0, 0.5, 0.1] {
            assert!((conductor(c, 1.5, 0.0) - dielectric(c, 1.5)).abs() < 1e-12);
        }
        // Grazing incidence reflects everything.
        assert!((conductor(0.0, 0.27, 3.4) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn four_lanes_equal_the_scalar_form() {
        let eta = [0.200438, 0.924033, 1.5, f64::NAN];
        let k = [3.91295, 2.45285, 0.0, 1.0];
        for &c in &[1.0, 0.93, 0.5, 0.1, 1e-9, 0.0, -0.2, f64::NAN] {
            let f = conductor4(c, &eta, &k);
            for l in 0..4 {
                let s = conductor(c, eta[l], k[l]);
                assert!(f[l].to_bits() == s.to_bits(), "cos {c} lane {l}: {} vs {s}", f[l]);
            }
        }
    }
}
