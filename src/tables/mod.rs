//! Tables the models read at run time, computed by this project's own
//! quadrature on first use and cached for the process, on one grid system:
//! an [`Axis`] places its nodes uniformly in a warped coordinate, a [`Grid`]
//! interpolates multilinearly between them, and [`build`] fills the rows of a
//! table over the available threads (the values do not depend on the split).
//!
//! This module depends on `microfacet/` (and the leaves `config`, `rng`,
//! `spectrum`) only. It holds the grid machinery and the tables more than one
//! model reads; a table that one model alone reads lives beside that model
//! (`models/auto/table.rs`, `models/analytic/dielectric_albedo.rs`) and uses
//! the machinery from here (docs/architecture.md).
//!
//! | file | table | used by |
//! |---|---|---|
//! | `albedo.rs` | conductor albedos with F = 1 over (α, μ): `single`, order 1 of the walks | `compensated`, the MIS density of the conductor walks |

pub mod albedo;

use crate::config::Distribution;
use std::sync::OnceLock;

/// The coordinate in which an axis places its nodes uniformly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Warp {
    /// x itself.
    Identity,
    /// √x (roughness: the albedos change fastest at high α).
    Sqrt,
    /// x² (cosines: denser towards grazing incidence), x clamped into [0, 1].
    Square,
    /// ln x (roughness and IOR ratios over decades).
    Ln,
    /// √(1 − 1/x²), the cosine of the critical angle of a relative IOR x ≥ 1
    /// (nodes crowd near 1, where the total-internal-reflection cone opens).
    CriticalCosine,
}

impl Warp {
    /// u = warp(x).
    #[inline]
    pub fn apply(self, x: f64) -> f64 {
        match self {
            Warp::Identity => x,
            Warp::Sqrt => x.sqrt(),
            Warp::Square => x.clamp(0.0, 1.0).powi(2),
            Warp::Ln => x.ln(),
            Warp::CriticalCosine => (1.0 - 1.0 / (x * x)).max(0.0).sqrt(),
        }
    }

    /// x = warp⁻¹(u).
    #[inline]
    pub fn invert(self, u: f64) -> f64 {
        match self {
            Warp::Identity => u,
            Warp::Sqrt => u.powi(2),
            Warp::Square => u.sqrt(),
            Warp::Ln => u.exp(),
            Warp::CriticalCosine => 1.0 / (1.0 - u * u).sqrt(),
        }
    }
}

/// `n` nodes uniform in the warped coordinate u = warp(x) between `lo` and
/// `hi` (given as u): at the ends (`centred = false`: u_i = lo + (hi − lo)·i/(n − 1))
/// or at the centres of n equal cells (`centred = true`: u_i = lo + (hi − lo)·(i + ½)/n).
#[derive(Clone, Copy, Debug)]
pub struct Axis {
    pub warp: Warp,
    pub lo: f64,
    pub hi: f64,
    pub n: usize,
    pub centred: bool,
}

impl Axis {
    /// Nodes at the ends of `n − 1` equal steps of warp(x) from `lo` to `hi` (u values).
    pub const fn ends(warp: Warp, lo: f64, hi: f64, n: usize) -> Axis {
        Axis { warp, lo, hi, n, centred: false }
    }

    /// Nodes at the centres of `n` equal cells of warp(x) from `lo` to `hi` (u values).
    pub const fn centred(warp: Warp, lo: f64, hi: f64, n: usize) -> Axis {
        Axis { warp, lo, hi, n, centred: true }
    }

    /// The value of node `i`.
    #[inline]
    pub fn node(&self, i: usize) -> f64 {
        let u = if self.centred {
            self.lo + (self.hi - self.lo) * ((i as f64 + 0.5) / self.n as f64)
        } else {
            self.lo + (self.hi - self.lo) * i as f64 / (self.n - 1) as f64
        };
        self.warp.invert(u)
    }

    /// The fractional node position of x, clamped to the axis (NaN counts as
    /// the first node).
    #[inline]
    pub fn position(&self, x: f64) -> f64 {
        let t = (self.warp.apply(x) - self.lo) / (self.hi - self.lo);
        let t = if self.centred { t * self.n as f64 - 0.5 } else { t * (self.n - 1) as f64 };
        if t.is_nan() {
            0.0
        } else {
            t.clamp(0.0, (self.n - 1) as f64)
        }
    }

    /// The cell (lower node) holding x and the fraction of the way to the next node.
    #[inline]
    pub fn locate(&self, x: f64) -> (usize, f64) {
        let t = self.position(x);
        // t ≥ 0: truncation is the floor (and needs no libm call on baseline x86-64).
        let i = (t as usize).min(self.n - 2);
        (i, t - i as f64)
    }
}

/// Values on the product of `D` axes, the last axis varying fastest.
#[derive(Clone, Debug)]
pub struct Grid<const D: usize> {
    pub axes: [Axis; D],
    pub values: Vec<f64>,
}

impl<const D: usize> Grid<D> {
    /// Number of values on the product of `axes`.
    pub fn size(axes: &[Axis; D]) -> usize {
        axes.iter().map(|a| a.n).product()
    }

    /// Multilinear interpolation at `x` (clamped to the grid): nested linear
    /// interpolations, the last axis innermost. At most [`MAX_AXES`] axes.
    #[inline]
    pub fn at(&self, x: [f64; D]) -> f64 {
        const { assert!(D >= 1 && D <= MAX_AXES) };
        let cells: [(usize, f64); D] = std::array::from_fn(|d| self.axes[d].locate(x[d]));
        // The 2^D corner values; bit D−1−d of a corner's index picks node i or i + 1 on axis d.
        let mut v = [0.0f64; 1 << MAX_AXES];
        for (corner, slot) in v.iter_mut().enumerate().take(1 << D) {
            let mut flat = 0;
            for (d, (axis, &(i, _))) in self.axes.iter().zip(&cells).enumerate() {
                flat = flat * axis.n + i + ((corner >> (D - 1 - d)) & 1);
            }
            *slot = self.values[flat];
        }
        let mut len = 1usize << D;
        // Pairs of neighbours differ on the last remaining axis: interpolate it away.
        for &(_, f) in cells.iter().rev() {
            len /= 2;
            for k in 0..len {
                v[k] = v[2 * k] * (1.0 - f) + v[2 * k + 1] * f;
            }
        }
        v[0]
    }
}

/// The most axes a [`Grid`] interpolates over.
pub const MAX_AXES: usize = 3;

/// Fills `rows` rows of `row_len` values each, row by row over the available
/// threads (at most 8): `fill(row, out)` computes row `row`.
pub fn build<T: Copy + Default + Send>(rows: usize, row_len: usize, fill: impl Fn(usize, &mut [T]) + Sync) -> Vec<T> {
    let mut values = vec![T::default(); rows * row_len];
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).clamp(1, 8);
    let per = rows.div_ceil(threads).max(1);
    std::thread::scope(|s| {
        for (t, chunk) in values.chunks_mut(per * row_len).enumerate() {
            let fill = &fill;
            s.spawn(move || {
                for (r, out) in chunk.chunks_mut(row_len).enumerate() {
                    fill(t * per + r, out);
                }
            });
        }
    });
    values
}

/// The table of distribution `dist`, computed by `compute` on first use and
/// kept in `cache` (GGX, Beckmann) for the process.
pub fn per_distribution<T: Sync + Send>(cache: &'static [OnceLock<T>; 2], dist: Distribution, compute: fn(Distribution) -> T) -> &'static T {
    let slot = match dist {
        Distribution::Ggx => &cache[0],
        Distribution::Beckmann => &cache[1],
    };
    slot.get_or_init(|| compute(dist))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interpolation written as nested linear interpolations, one axis at a
    /// time (the definition `Grid::at` must reproduce bit for bit).
    fn nested<const D: usize>(g: &Grid<D>, cells: &[(usize, f64); D], d: usize, base: usize) -> f64 {
        if d == D {
            return g.values[base];
        }
        let (i, f) = cells[d];
        let n = g.axes[d].n;
        let lower = nested(g, cells, d + 1, base * n + i);
        let upper = nested(g, cells, d + 1, base * n + i + 1);
        lower * (1.0 - f) + upper * f
    }

    fn check<const D: usize>(axes: [Axis; D]) {
        let values: Vec<f64> = (0..Grid::size(&axes)).map(|i| ((i * 7919) % 1009) as f64 / 1009.0 - 0.3).collect();
        let g = Grid { axes, values };
        let mut st = 1u64;
        let mut rnd = || {
            st = crate::rng::mix64(st.wrapping_add(1));
            (st >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            // Inside the grid, beyond both ends and NaN (clamped, first node).
            let x: [f64; D] = std::array::from_fn(|d| match (rnd() * 20.0) as u32 {
                0 => f64::NAN,
                1 => -1.0,
                2 => 1e3,
                _ => g.axes[d].node(0) + rnd() * (g.axes[d].node(g.axes[d].n - 1) - g.axes[d].node(0)),
            });
            let cells: [(usize, f64); D] = std::array::from_fn(|d| g.axes[d].locate(x[d]));
            assert_eq!(g.at(x).to_bits(), nested(&g, &cells, 0, 0).to_bits(), "at {x:?}");
        }
    }

    #[test]
    fn at_is_nested_linear_interpolation() {
        check([Axis::ends(Warp::Sqrt, 0.1, 2.0, 9)]);
        check([Axis::ends(Warp::Sqrt, 0.1, 2.0, 9), Axis::centred(Warp::Square, 0.0, 1.0, 7)]);
        check([Axis::ends(Warp::Ln, -3.0, 1.0, 5), Axis::ends(Warp::CriticalCosine, 0.0, 0.9, 4), Axis::ends(Warp::Identity, 0.0, 1.0, 6)]);
    }
}
