//! Random periodic height fields with Beckmann slope statistics.
//!
//! A stationary Gaussian process with the Gaussian autocorrelation
//! C(r) = σ² exp(−|r|²/ℓ²) is synthesised spectrally on an n×n periodic grid
//! (power spectrum ∝ exp(−|k|²ℓ²/4), random complex amplitudes, one inverse
//! FFT; the real and imaginary parts are two independent realisations). The
//! grid is built in *index space* (unit spacing, isotropic, ℓ given in cells,
//! σ = 1) and then stretched: the physical cell sizes dx, dy are chosen so that
//! the finite differences along x and y have the variances α_x²/2 and α_y²/2.
//!
//! The surface is the piecewise-linear interpolation of the grid: two triangles
//! per cell, the diagonal alternating in a checkerboard (cells with i + j even
//! are split along (0,0)–(1,1), the others along (1,0)–(0,1)), so that the
//! triangulation is symmetric under x ↦ −x and y ↦ −y. Every triangle's slopes
//! are forward differences of the process, hence exactly Gaussian with the
//! variances α²/2 of Beckmann's slope distribution P22, and every triangle has
//! the same projected area: the unweighted facet histogram is P22 (Beckmann's D
//! is P22(slope)/cos⁴θ_m). The only departure from Beckmann is a small
//! correlation ±c between a triangle's x and y slopes (+ on one diagonal, − on
//! the other), c = (1 − 2ρ(1) + ρ(√2))/(2(1 − ρ(1))) in terms of the index-space
//! correlation ρ: 0.7 % at ℓ = 8 cells, 0.2 % at ℓ = 16
//! ([`HeightField::facet_slope_correlation`]).
//!
//! Statistics are exact for the ensemble of surfaces; one finite surface
//! deviates from them by its sampling error, which the tests and the
//! simulation estimate from independent realisations (docs/microgeometry.md).

use super::fft::fft2;
use crate::rng::{hash_words, Sampler};
use std::f64::consts::PI;

/// Parameters of a generated surface.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceParams {
    /// Beckmann roughness along x and y (slope variances α²/2).
    pub alpha_x: f64,
    pub alpha_y: f64,
    /// Vertices per side (a power of two, ≥ 16); the field is periodic.
    pub grid: usize,
    /// Correlation length ℓ of the process in cells (ℓ ≥ 2; 8 resolves it well).
    pub corr_cells: f64,
}

impl SurfaceParams {
    pub fn validate(&self) -> Result<(), String> {
        let ok_alpha = |a: f64| a.is_finite() && (1e-3..=10.0).contains(&a);
        if !ok_alpha(self.alpha_x) || !ok_alpha(self.alpha_y) {
            return Err(format!("alpha must lie in [0.001, 10], got ({}, {})", self.alpha_x, self.alpha_y));
        }
        if !(self.grid.is_power_of_two() && (16..=8192).contains(&self.grid)) {
            return Err(format!("grid must be a power of two in [16, 8192], got {}", self.grid));
        }
        if !(self.corr_cells.is_finite() && self.corr_cells >= 2.0 && self.corr_cells <= self.grid as f64 / 4.0) {
            return Err(format!("corr_cells must lie in [2, grid/4 = {}], got {}", self.grid / 4, self.corr_cells));
        }
        Ok(())
    }
}

/// Cells per side of an acceleration block (min/max heights per block).
pub(crate) const BLOCK: usize = 8;

/// A periodic piecewise-linear height field (heights in units of σ).
#[derive(Clone, Debug)]
pub struct HeightField {
    pub(crate) n: usize,
    /// Heights h[j·n + i] at the vertex (i·dx, j·dy), stored in single
    /// precision (half the memory; the surface *is* these values, so every
    /// computation sees the same triangles).
    pub(crate) h: Vec<f32>,
    /// Physical cell sizes.
    pub dx: f64,
    pub dy: f64,
    pub zmin: f64,
    pub zmax: f64,
    /// Per block of BLOCK×BLOCK cells: min and max of its vertices' heights.
    pub(crate) bmin: Vec<f64>,
    pub(crate) bmax: Vec<f64>,
    /// Index-space correlation at one and √2 cells (for the facet statistics).
    rho1: f64,
    rho_diag: f64,
}

/// Two independent standard normal numbers (Box–Muller).
fn normal_pair(rng: &mut Sampler) -> (f64, f64) {
    let u1 = 1.0 - rng.next(); // (0, 1]
    let u2 = rng.next();
    let r = (-2.0 * u1.ln()).sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    (r * c, r * s)
}

/// Signed frequency index of FFT position p (the Nyquist index n/2 maps to −n/2).
fn freq(p: usize, n: usize) -> i64 {
    if p < n / 2 {
        p as i64
    } else {
        p as i64 - n as i64
    }
}

impl HeightField {
    /// Two independent surfaces from one spectral synthesis (real and imaginary
    /// parts of the inverse FFT of complex Gaussian amplitudes). `seed` selects
    /// the realisation.
    pub fn generate_pair(p: &SurfaceParams, seed: u64) -> Result<[HeightField; 2], String> {
        p.validate()?;
        let n = p.grid;
        let l = p.corr_cells;
        // Spectral weights w_k ∝ exp(−|k|²ℓ²/4), k = 2π m/n; zero at the Nyquist
        // frequency (it has no −k partner, which would correlate the two parts).
        let mut w = vec![0.0; n * n];
        for py in 0..n {
            for px in 0..n {
                let (mx, my) = (freq(px, n), freq(py, n));
                if mx == -(n as i64) / 2 || my == -(n as i64) / 2 {
                    continue;
                }
                let (kx, ky) = (2.0 * PI * mx as f64 / n as f64, 2.0 * PI * my as f64 / n as f64);
                w[py * n + px] = (-(kx * kx + ky * ky) * l * l / 4.0).exp();
            }
        }
        let total: f64 = w.iter().sum();
        w.iter_mut().for_each(|x| *x /= total);
        // Index-space correlations ρ(e_x) and ρ(e_x + e_y) of the discrete process.
        let (mut rho1, mut rho_diag) = (0.0, 0.0);
        for py in 0..n {
            for px in 0..n {
                let (kx, ky) = (2.0 * PI * freq(px, n) as f64 / n as f64, 2.0 * PI * freq(py, n) as f64 / n as f64);
                rho1 += w[py * n + px] * kx.cos();
                rho_diag += w[py * n + px] * (kx + ky).cos();
            }
        }
        let mut rng = Sampler::new(hash_words(&[0x6d69_6372_6f67_656f, seed]));
        let (mut re, mut im) = (vec![0.0; n * n], vec![0.0; n * n]);
        for i in 0..n * n {
            let (a, b) = normal_pair(&mut rng);
            let s = w[i].sqrt();
            re[i] = s * a;
            im[i] = s * b;
        }
        fft2(&mut re, &mut im, n, true);
        // Finite differences have variance 2(1 − ρ(1)) in index space; the cell
        // sizes make the physical slope variances α²/2.
        let var_diff = 2.0 * (1.0 - rho1);
        let dx = (2.0 * var_diff).sqrt() / p.alpha_x;
        let dy = (2.0 * var_diff).sqrt() / p.alpha_y;
        Ok([HeightField::from_heights(n, re, dx, dy, rho1, rho_diag), HeightField::from_heights(n, im, dx, dy, rho1, rho_diag)])
    }

    fn from_heights(n: usize, h: Vec<f64>, dx: f64, dy: f64, rho1: f64, rho_diag: f64) -> HeightField {
        let h: Vec<f32> = h.iter().map(|&x| x as f32).collect();
        let nb = n / BLOCK;
        let (mut bmin, mut bmax) = (vec![f64::INFINITY; nb * nb], vec![f64::NEG_INFINITY; nb * nb]);
        for bj in 0..nb {
            for bi in 0..nb {
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for j in 0..=BLOCK {
                    for i in 0..=BLOCK {
                        let v = h[((bj * BLOCK + j) % n) * n + (bi * BLOCK + i) % n] as f64;
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
                bmin[bj * nb + bi] = lo;
                bmax[bj * nb + bi] = hi;
            }
        }
        let zmin = h.iter().map(|&x| x as f64).fold(f64::INFINITY, f64::min);
        let zmax = h.iter().map(|&x| x as f64).fold(f64::NEG_INFINITY, f64::max);
        HeightField { n, h, dx, dy, zmin, zmax, bmin, bmax, rho1, rho_diag }
    }

    /// Vertices per side.
    pub fn grid(&self) -> usize {
        self.n
    }

    /// Period of the surface along x and y (physical units).
    pub fn period(&self) -> (f64, f64) {
        (self.n as f64 * self.dx, self.n as f64 * self.dy)
    }

    /// Height of vertex (i, j), periodic in both indices.
    #[inline]
    pub fn vertex(&self, i: i64, j: i64) -> f64 {
        let m = (self.n - 1) as i64;
        self.h[((j & m) as usize) * self.n + (i & m) as usize] as f64
    }

    /// Ensemble correlation coefficient of the x and y slopes within one
    /// triangle (positive on one diagonal, negative on the other).
    pub fn facet_slope_correlation(&self) -> f64 {
        (1.0 - 2.0 * self.rho1 + self.rho_diag) / (2.0 * (1.0 - self.rho1))
    }

    /// Plane of triangle `tri` (0 or 1) of cell (ci, cj) in the cell's local
    /// index coordinates (u, v) ∈ [0, 1]²: H = c + bx·u + by·v.
    #[inline]
    pub(crate) fn plane(&self, ci: i64, cj: i64, tri: u32) -> (f64, f64, f64) {
        let h00 = self.vertex(ci, cj);
        let h10 = self.vertex(ci + 1, cj);
        let h01 = self.vertex(ci, cj + 1);
        let h11 = self.vertex(ci + 1, cj + 1);
        Self::plane_of(((ci + cj) & 1) == 0, tri, h00, h10, h01, h11)
    }

    #[inline]
    pub(crate) fn plane_of(diag_a: bool, tri: u32, h00: f64, h10: f64, h01: f64, h11: f64) -> (f64, f64, f64) {
        match (diag_a, tri) {
            // Diagonal (0,0)–(1,1): triangle 0 is u ≥ v, triangle 1 is u < v.
            (true, 0) => (h00, h10 - h00, h11 - h10),
            (true, _) => (h00, h11 - h01, h01 - h00),
            // Diagonal (1,0)–(0,1): triangle 0 is u + v ≤ 1, triangle 1 the rest.
            (false, 0) => (h00, h10 - h00, h01 - h00),
            (false, _) => {
                let (bx, by) = (h11 - h01, h11 - h10);
                (h11 - bx - by, bx, by)
            }
        }
    }

    /// Which triangle of a cell holds the local point (u, v).
    #[inline]
    pub(crate) fn triangle_at(diag_a: bool, u: f64, v: f64) -> u32 {
        if diag_a {
            u32::from(u < v)
        } else {
            u32::from(u + v > 1.0)
        }
    }

    /// Physical slopes (∂h/∂x, ∂h/∂y) of a plane given in index units.
    #[inline]
    pub(crate) fn slopes(&self, bx: f64, by: f64) -> (f64, f64) {
        (bx / self.dx, by / self.dy)
    }

    /// Calls `f(slope_x, slope_y)` for every triangle (2n² of them, equal
    /// projected areas).
    pub fn for_each_facet(&self, mut f: impl FnMut(f64, f64)) {
        let n = self.n as i64;
        for cj in 0..n {
            for ci in 0..n {
                for tri in 0..2 {
                    let (_, bx, by) = self.plane(ci, cj, tri);
                    let (sx, sy) = self.slopes(bx, by);
                    f(sx, sy);
                }
            }
        }
    }

    /// The surface point above the physical (x, y): its height, the triangle's
    /// id (2·cell + tri) and its index-space plane slopes.
    pub fn surface_at(&self, x: f64, y: f64) -> (f64, u64, f64, f64) {
        let (fx, fy) = (x / self.dx, y / self.dy);
        let (ci, cj) = (fx.floor() as i64, fy.floor() as i64);
        let (u, v) = (fx - ci as f64, fy - cj as f64);
        let diag_a = ((ci + cj) & 1) == 0;
        let tri = Self::triangle_at(diag_a, u, v);
        let (c, bx, by) = self.plane(ci, cj, tri);
        (c + bx * u + by * v, self.triangle_id(ci, cj, tri), bx, by)
    }

    #[inline]
    pub(crate) fn triangle_id(&self, ci: i64, cj: i64, tri: u32) -> u64 {
        let m = (self.n - 1) as i64;
        (((cj & m) as u64) * self.n as u64 + (ci & m) as u64) * 2 + tri as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn process_variance_and_difference_variance_are_exact_in_the_ensemble() {
        // Average over realisations: Var(h) = 1 and Var(Δ_x h)/dx² = α_x²/2.
        let p = SurfaceParams { alpha_x: 0.5, alpha_y: 0.2, grid: 64, corr_cells: 6.0 };
        let (mut v, mut sx, mut sy, mut count) = (0.0, 0.0, 0.0, 0.0);
        for seed in 0..20 {
            for f in HeightField::generate_pair(&p, seed).unwrap() {
                for j in 0..64 {
                    for i in 0..64 {
                        let h = f.vertex(i, j);
                        v += h * h;
                        sx += ((f.vertex(i + 1, j) - h) / f.dx).powi(2);
                        sy += ((f.vertex(i, j + 1) - h) / f.dy).powi(2);
                        count += 1.0;
                    }
                }
            }
        }
        // 40 surfaces of ≈ (64/6)² ≈ 110 correlation areas each: ≈ 2 % relative error per mean square.
        assert!((v / count - 1.0).abs() < 0.1, "Var h = {}", v / count);
        assert!((sx / count / (0.125) - 1.0).abs() < 0.1, "Var sx = {}", sx / count);
        assert!((sy / count / (0.02) - 1.0).abs() < 0.1, "Var sy = {}", sy / count);
    }

    #[test]
    fn surface_point_lies_on_the_triangulation() {
        let p = SurfaceParams { alpha_x: 0.7, alpha_y: 0.7, grid: 16, corr_cells: 3.0 };
        let [f, _] = HeightField::generate_pair(&p, 1).unwrap();
        // Vertices are reproduced, and the surface is continuous across edges.
        for &(i, j) in &[(0i64, 0i64), (3, 5), (15, 15), (16, 2)] {
            let (z, _, _, _) = f.surface_at(i as f64 * f.dx + 1e-12, j as f64 * f.dy + 1e-12);
            assert!((z - f.vertex(i, j)).abs() < 1e-9);
        }
        let mut rng = Sampler::new(5);
        for _ in 0..1000 {
            let (x, y) = (rng.next() * 16.0 * f.dx, rng.next() * 16.0 * f.dy);
            let e = 1e-9;
            let (z0, ..) = f.surface_at(x, y);
            for (ddx, ddy) in [(e, 0.0), (0.0, e), (-e, e)] {
                let (z1, ..) = f.surface_at(x + ddx * f.dx, y + ddy * f.dy);
                assert!((z1 - z0).abs() < 1e-6, "discontinuity at ({x}, {y})");
            }
        }
    }
}
