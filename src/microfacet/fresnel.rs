//! Fresnel reflectance: conductors with a complex index of refraction η + ik
//! (per channel), and real dielectrics.

/// Unpolarised Fresnel reflectance of a conductor with relative complex IOR
/// η + ik at an incidence cosine `cos_i` (> 0). Exact (not Schlick): the
/// classic closed form in terms of a² + b² with (a + ib)² = η̃² − sin²θ.
#[inline]
pub fn conductor(cos_i: f64, eta: f64, k: f64) -> f64 {
    let c2 = (cos_i * cos_i).min(1.0);
    let s2 = 1.0 - c2;
    let t = eta * eta - k * k - s2;
    let a2b2 = (t * t + 4.0 * eta * eta * k * k).max(0.0).sqrt();
    let a = (0.5 * (a2b2 + t)).max(0.0).sqrt();
    let t1 = a2b2 + c2;
    let t2 = 2.0 * cos_i * a;
    let rs = (t1 - t2) / (t1 + t2);
    let t3 = a2b2 * c2 + s2 * s2;
    let t4 = t2 * s2;
    let rp = rs * (t3 - t4) / (t3 + t4);
    let f = 0.5 * (rs + rp);
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// Unpolarised Fresnel reflectance of a dielectric interface with relative IOR
/// `eta` = η_t/η_i, for incidence cosine `cos_i` (taken in absolute value).
/// Returns 1 under total internal reflection.
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
}
