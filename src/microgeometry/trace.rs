//! Exact ray traversal of a periodic piecewise-linear height field.
//!
//! The surface is the graph z = H(x, y). A ray on the *outside* (above, z > H)
//! hits where z − H changes sign; a ray on the *inside* (below, in a
//! dielectric) where H − z does. Along a ray, z − H is linear on every piece of
//! the ray above one triangle, so each piece is tested in closed form: the
//! signed gap g(t) = side·(z(t) − H(t)) is g₀ + s·(t − t₀), and the ray hits at
//! t₀ + g₀/(−s) if that lies in the piece. Since every piece of the ray is
//! examined in order, no crack or seam can let a ray through: a ray found on
//! the wrong side (g₀ ≤ 0, by rounding at an edge) while moving into the
//! surface counts as a hit at once.
//!
//! Traversal is a two-level 2D DDA (Amanatides & Woo) in index space (cell
//! size 1): blocks of 8×8 cells whose height range the ray's height range over
//! the block does not meet are skipped; inside the others the ray visits each
//! cell, rejects it by the cell's height range, and otherwise tests the cell's
//! two triangles (split where the ray crosses the cell's diagonal).

use super::surface::{HeightField, BLOCK};
use glam::DVec3;

/// Which side of the surface a ray travels on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Above the surface (in air).
    Outside,
    /// Below the surface (inside a dielectric).
    Inside,
}

impl Side {
    #[inline]
    fn sign(self) -> f64 {
        match self {
            Side::Outside => 1.0,
            Side::Inside => -1.0,
        }
    }
}

/// Where a ray ends.
#[derive(Clone, Copy, Debug)]
pub enum Trace {
    /// Hits the surface at `pos` on triangle `tri` with unit normal `normal`
    /// (pointing up, to the outside).
    Hit { pos: DVec3, tri: u64, normal: DVec3 },
    /// Leaves the surface's height range for good (up from the outside, down
    /// from the inside).
    Escape,
    /// Numerical failure: found beyond the surface on the wrong side, or
    /// travelled further than the step limit (near-horizontal rays). Counted
    /// and reported by the simulation.
    Lost,
}

/// Amanatides–Woo traversal of a 2D grid of square cells of side `size`.
struct Dda {
    cell: [i64; 2],
    step: [i64; 2],
    t_next: [f64; 2],
    t_delta: [f64; 2],
    /// t at which the ray entered the current cell.
    t_enter: f64,
}

impl Dda {
    /// Starts at parameter `t0` on the ray o + t·d (2D, grid units of `size`).
    #[inline]
    fn new(o: [f64; 2], d: [f64; 2], t0: f64, size: f64) -> Dda {
        let mut cell = [0i64; 2];
        let mut step = [0i64; 2];
        let mut t_next = [f64::INFINITY; 2];
        let mut t_delta = [f64::INFINITY; 2];
        for a in 0..2 {
            let p = (o[a] + t0 * d[a]) / size;
            let c = p.floor();
            cell[a] = c as i64;
            if d[a] > 0.0 {
                step[a] = 1;
                t_delta[a] = size / d[a];
                t_next[a] = ((c + 1.0) * size - o[a]) / d[a];
            } else if d[a] < 0.0 {
                step[a] = -1;
                t_delta[a] = -size / d[a];
                t_next[a] = (c * size - o[a]) / d[a];
            }
            // Guard against rounding putting the next boundary behind t0.
            if t_next[a] < t0 {
                t_next[a] = t0;
            }
        }
        Dda { cell, step, t_next, t_delta, t_enter: t0 }
    }

    #[inline]
    fn t_exit(&self) -> f64 {
        self.t_next[0].min(self.t_next[1])
    }

    #[inline]
    fn advance(&mut self) {
        let a = usize::from(self.t_next[1] < self.t_next[0]);
        self.t_enter = self.t_next[a];
        self.cell[a] += self.step[a];
        self.t_next[a] += self.t_delta[a];
    }
}

/// The ray in index space: positions (x/dx, y/dy, z), same parameter t.
struct IndexRay {
    o: [f64; 3],
    d: [f64; 3],
    side: f64,
}

impl IndexRay {
    #[inline]
    fn z(&self, t: f64) -> f64 {
        if t.is_infinite() {
            // Only for rays without horizontal motion.
            return if self.d[2] > 0.0 {
                f64::INFINITY
            } else if self.d[2] < 0.0 {
                f64::NEG_INFINITY
            } else {
                self.o[2]
            };
        }
        self.o[2] + t * self.d[2]
    }
}

/// Largest number of blocks one trace may visit before the ray counts as lost.
const MAX_BLOCK_STEPS: usize = 1 << 22;

impl HeightField {
    /// First intersection of the ray `o + t·d` (t > 0, physical units) with the
    /// surface, for a ray travelling on `side`; `skip` is the triangle the ray
    /// leaves from (a plane is never hit twice by a straight ray).
    pub fn trace(&self, o: DVec3, d: DVec3, side: Side, skip: Option<u64>) -> Trace {
        let (px, py) = self.period();
        // Wrap the origin into the base period (the surface is periodic).
        let ox = o.x - (o.x / px).floor() * px;
        let oy = o.y - (o.y / py).floor() * py;
        let ray = IndexRay { o: [ox / self.dx, oy / self.dy, o.z], d: [d.x / self.dx, d.y / self.dy, d.z], side: side.sign() };
        let skip = skip.unwrap_or(u64::MAX);
        let nb = (self.n / BLOCK) as i64;
        let mut blocks = Dda::new([ray.o[0], ray.o[1]], [ray.d[0], ray.d[1]], 0.0, BLOCK as f64);
        for _ in 0..MAX_BLOCK_STEPS {
            let (t0, t1) = (blocks.t_enter, blocks.t_exit());
            let z0 = ray.z(t0);
            // Escape and numerical-failure tests at the block entry.
            match side {
                Side::Outside => {
                    if z0 > self.zmax && ray.d[2] >= 0.0 {
                        return Trace::Escape;
                    }
                    if z0 < self.zmin && ray.d[2] < 0.0 {
                        return Trace::Lost;
                    }
                }
                Side::Inside => {
                    if z0 < self.zmin && ray.d[2] <= 0.0 {
                        return Trace::Escape;
                    }
                    if z0 > self.zmax && ray.d[2] > 0.0 {
                        return Trace::Lost;
                    }
                }
            }
            let z1 = ray.z(t1);
            let bidx = (blocks.cell[1].rem_euclid(nb) * nb + blocks.cell[0].rem_euclid(nb)) as usize;
            let meets = match side {
                Side::Outside => z0.min(z1) <= self.bmax[bidx],
                Side::Inside => z0.max(z1) >= self.bmin[bidx],
            };
            if meets {
                if let Some(hit) = self.trace_block(&ray, t0, t1, skip) {
                    return hit;
                }
            }
            if t1.is_infinite() {
                // A vertical ray that met nothing in its column: it leaves if it
                // moves away from the surface, otherwise it slipped through.
                let away = ray.side * ray.d[2] > 0.0;
                return if away { Trace::Escape } else { Trace::Lost };
            }
            blocks.advance();
        }
        Trace::Lost
    }

    /// Cell-level traversal of the ray over [t0, t1] (one block).
    #[inline]
    fn trace_block(&self, ray: &IndexRay, t0: f64, t1: f64, skip: u64) -> Option<Trace> {
        let mut cells = Dda::new([ray.o[0], ray.o[1]], [ray.d[0], ray.d[1]], t0, 1.0);
        loop {
            let ta = cells.t_enter;
            if ta > t1 {
                return None;
            }
            let tb = cells.t_exit();
            if let Some(hit) = self.hit_cell(ray, cells.cell[0], cells.cell[1], ta, tb, skip) {
                return Some(hit);
            }
            if tb >= t1 {
                return None;
            }
            cells.advance();
        }
    }

    /// Tests the two triangles of cell (ci, cj) over the ray piece [ta, tb].
    #[inline]
    fn hit_cell(&self, ray: &IndexRay, ci: i64, cj: i64, ta: f64, tb: f64, skip: u64) -> Option<Trace> {
        let h00 = self.vertex(ci, cj);
        let h10 = self.vertex(ci + 1, cj);
        let h01 = self.vertex(ci, cj + 1);
        let h11 = self.vertex(ci + 1, cj + 1);
        let (za, zb) = (ray.z(ta), ray.z(tb));
        if ray.side > 0.0 {
            if za.min(zb) > h00.max(h10).max(h01.max(h11)) {
                return None;
            }
        } else if za.max(zb) < h00.min(h10).min(h01.min(h11)) {
            return None;
        }
        let diag_a = ((ci + cj) & 1) == 0;
        // Local coordinates u = x − ci, v = y − cj along the ray.
        let (u0, v0) = (ray.o[0] - ci as f64, ray.o[1] - cj as f64);
        let (du, dv) = (ray.d[0], ray.d[1]);
        // The diagonal q = 0: q = u − v (diagonal A) or u + v − 1 (diagonal B).
        let (q0, dq) = if diag_a { (u0 - v0, du - dv) } else { (u0 + v0 - 1.0, du + dv) };
        let mut cuts = [ta, tb, tb];
        let mut pieces = 1;
        if dq != 0.0 {
            let tc = -q0 / dq;
            if tc > ta && tc < tb {
                cuts = [ta, tc, tb];
                pieces = 2;
            }
        }
        for k in 0..pieces {
            let (t0, t1) = (cuts[k], cuts[k + 1]);
            let tm = if t1.is_finite() { 0.5 * (t0 + t1) } else { t0 + 1.0 };
            let tri = HeightField::triangle_at(diag_a, u0 + tm * du, v0 + tm * dv);
            let id = self.triangle_id(ci, cj, tri);
            if id == skip {
                continue;
            }
            let (c, bx, by) = HeightField::plane_of(diag_a, tri, h00, h10, h01, h11);
            let g0 = ray.side * (ray.o[2] + t0 * ray.d[2] - c - bx * (u0 + t0 * du) - by * (v0 + t0 * dv));
            let s = ray.side * (ray.d[2] - bx * du - by * dv);
            let t_hit = if g0 <= 0.0 {
                // Already on the far side (rounding at an edge): a hit only if
                // the ray moves further into this plane.
                if s <= 0.0 {
                    t0
                } else {
                    continue;
                }
            } else if s < 0.0 {
                let t = t0 + g0 / -s;
                if t <= t1 {
                    t
                } else {
                    continue;
                }
            } else {
                continue;
            };
            let (u, v) = (u0 + t_hit * du, v0 + t_hit * dv);
            let pos = DVec3::new((ci as f64 + u) * self.dx, (cj as f64 + v) * self.dy, c + bx * u + by * v);
            let (sx, sy) = self.slopes(bx, by);
            let normal = DVec3::new(-sx, -sy, 1.0).normalize();
            return Some(Trace::Hit { pos, tri: id, normal });
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::super::surface::SurfaceParams;
    use super::*;
    use crate::rng::Sampler;

    fn field() -> HeightField {
        let p = SurfaceParams { alpha_x: 0.8, alpha_y: 0.5, grid: 64, corr_cells: 5.0 };
        let [f, _] = HeightField::generate_pair(&p, 9).unwrap();
        f
    }

    #[test]
    fn downward_rays_hit_the_surface_below_their_origin() {
        // A vertical ray from above hits exactly the surface point under it.
        let f = field();
        let mut rng = Sampler::new(1);
        let (px, py) = f.period();
        for _ in 0..2000 {
            let (x, y) = (rng.next() * px, rng.next() * py);
            match f.trace(DVec3::new(x, y, f.zmax + 1.0), DVec3::new(0.0, 0.0, -1.0), Side::Outside, None) {
                Trace::Hit { pos, normal, .. } => {
                    let (z, _, _, _) = f.surface_at(x, y);
                    assert!((pos.z - z).abs() < 1e-9 && (pos.x - x).abs() < 1e-9, "{pos} vs ({x}, {y}, {z})");
                    assert!(normal.z > 0.0);
                }
                t => panic!("vertical ray did not hit: {t:?}"),
            }
        }
    }

    #[test]
    fn hits_agree_with_brute_force_marching() {
        // The first crossing found by traversal equals the one found by fine
        // marching of z − H along the ray, for oblique rays from above and from below.
        let f = field();
        let mut rng = Sampler::new(2);
        let (px, py) = f.period();
        let mut checked = 0;
        for k in 0..400 {
            let side = if k % 2 == 0 { Side::Outside } else { Side::Inside };
            let theta: f64 = 0.2 + 1.2 * rng.next();
            let phi: f64 = std::f64::consts::TAU * rng.next();
            let dz = if side == Side::Outside { -theta.cos() } else { theta.cos() };
            let d = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), dz);
            let (x, y) = (rng.next() * px, rng.next() * py);
            let z0 = if side == Side::Outside { f.zmax + 0.1 } else { f.zmin - 0.1 };
            let o = DVec3::new(x, y, z0);
            let gap = |t: f64| {
                let p = o + t * d;
                let (h, ..) = f.surface_at(p.x.rem_euclid(px), p.y.rem_euclid(py));
                (p.z - h) * if side == Side::Outside { 1.0 } else { -1.0 }
            };
            let step = 1e-3 * f.dx.min(f.dy);
            let mut t = 0.0;
            while gap(t + step) > 0.0 {
                t += step;
            }
            match f.trace(o, d, side, None) {
                Trace::Hit { pos, .. } => {
                    let th = (pos - o).length();
                    assert!(th >= t - 1e-9 && th <= t + step + 1e-9, "traversal t = {th}, marching in [{t}, {}]", t + step);
                    checked += 1;
                }
                tr => panic!("no hit: {tr:?}"),
            }
        }
        assert_eq!(checked, 400);
    }

    #[test]
    fn upward_rays_from_above_escape() {
        let f = field();
        let o = DVec3::new(1.0, 2.0, f.zmax + 1e-6);
        assert!(matches!(f.trace(o, DVec3::new(0.6, 0.0, 0.8), Side::Outside, None), Trace::Escape));
        let o = DVec3::new(1.0, 2.0, f.zmin - 1e-6);
        assert!(matches!(f.trace(o, DVec3::new(0.6, 0.0, -0.8), Side::Inside, None), Trace::Escape));
    }
}
