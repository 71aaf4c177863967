//! Multiple-bounce Smith microfacet BRDF from the invariance principle,
//! Cui et al. 2023, for conductors, with the corrected readings of docs/paper-notes.md.
//!
//! **Path contribution** (supplement eq. 1). A path d_0 = −ω_i, d_1, …, d_k = ω_o
//! (directions follow the light) contributes (Π_{j<k} v_j)·S_k(d_0..d_k) to
//! f·cos θ_o, with Wang's vertex terms v_j = F·D(h_j)/(4|cos d_j|) and the
//! segment term of the complete invariance recursion
//!
//! S_k(d_0..d_k) = S_1(d_0,d_k)·Σ_{j=0}^{k−1} S_j(d_0..d_j)·S_{k−1−j}(d_{j+1}..d_k),
//! S_1(a,b) = 1/(|Λ(a)| + Λ(b)), S_0 ≡ 1, S_m = 0 when its first direction
//! points up or its last points down.
//!
//! **Exit probabilities.** Write L_j = |Λ(d_j)|. Then
//! p_exit(d_0..d_k) = (Π_{j<k} L_j)·S_k (supplement eq. 7) is the probability
//! that a ray following the directions hits the microsurface at every vertex and
//! leaves along d_k (Bitterli & d'Eon 2022, heights integrated out), and
//! H_m = p_exit(d_0..d_m, ẑ) (Λ(ẑ) = 0: a vertical ray always leaves) is the
//! probability that d_0..d_m all hit. With P(i,j) = Π_{l=i}^{j−1} L_l and
//! p(i,j) = P(i,j)·S(i,j) the sub-sequence recursion reads
//!
//! p(i,j) = S_1(d_i,d_j)·Σ_{l=i}^{j−1} L_l·p(i,l)·p(l+1,j),   p(i,i) = 1,
//!
//! all terms positive (stable), and every p is a probability.
//!
//! **Monotone paths.** A conductor reflects an upward ray upward
//! (d'.z = d.z − 2(d·m)m.z > d.z for a front-facing m), so conductor paths are
//! a run of a ≥ 1 downward directions followed by upward ones. Then only the
//! j = 0 and j = k−1 terms of the recursion survive (the printed eq. 2):
//! S(i,j) = S_1(i,j)·(S(i+1,j) + S(i,j−1)), and in the scaled form
//!
//! p(i,j) = (L_i·p(i+1,j) + L_{j−1}·p(i,j−1)) / (L_i + Λ_j),   p(j,j) = 1,
//!
//! where p(i+1,j) is dropped when d_{i+1} points up (i+1 < j) and p(i,j−1) when
//! d_{j−1} points down (j−1 > i). For fixed down directions d_0..d_{a−1} a new
//! upward direction adds one column p(·, j) of length a: O(a) per vertex,
//! O(k²) per path at worst ([`MonotoneExit`]).
//!
//! **Estimators.** `eval`: sample d_{j+1} by reflecting −d_j about a visible
//! normal (density v_j/(F_j·L_j)); the NEE at vertex m towards ω_o then weighs
//! Π_{j≤m}F_j · D(h)/(4A(−d_m)) · p_exit(d_0..d_m, ω_o). The walk carries the
//! conditional hit probabilities H_{m}/H_{m−1} in its throughput and plays
//! Russian roulette on it after the vertex's estimates (sure survival while the
//! weight is ≥ 1/2, `RR_KEEP`); the heights are integrated out exactly. The
//! walk stops as soon as an upward direction is at least as steep as ω_o:
//! z only grows along the upward run, so no later vertex can reach ω_o (their
//! estimates are exactly 0; not a truncation). For orders 2 and 3 the last
//! inner direction is also sampled from the side of ω_o and the two strategies
//! are combined with the balance heuristic (a one-vertex light subpath, one
//! per call; closed form because the model is position-free).
//! `sample`: the same walk with exit
//! probability 1 − H_m/H_{m−1} at each upward direction; the sampling density
//! is then exactly the path contribution divided by Π F, so the weight is the
//! product of the Fresnel terms (Cui Alg. 2 with the exact exit probability —
//! the printed 1/|Λ(d_k)|, or G1(d_k) = 1/(1+Λ(d_k)), needs a weight ratio).
//!
//! **Efficiency** of `eval` against Heitz's walk (`benches/models.rs`, copper,
//! GGX; 1/(variance per call × time per call), one run at commit bedc5ec):
//! off-specular 6.1× at α = 0.5 and 3.5× at α = 1 (variance 5.5× and 3.2×
//! lower, 0.89× and 0.92× the time per call); grazing 21× / 7.8×; mirror
//! 3.2× / 1.9×.

use super::{russian_roulette_keep, vertex_numbers, ConductorFresnel, WalkOptions};
use crate::microfacet::{reflect, Microfacet};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// S_1(a, b) = 1/(|Λ(a)| + Λ(b)) for a downward, b upward; 0 otherwise.
#[inline]
fn s1(la: f64, a_down: bool, lb: f64, b_up: bool) -> f64 {
    if a_down && b_up {
        1.0 / (la + lb)
    } else {
        0.0
    }
}

/// (|Λ(d)|, d points down) for every direction. Λ(d) = |Λ(d)| for upward d.
fn lambdas(mf: &Microfacet, dirs: &[DVec3]) -> Vec<(f64, bool)> {
    dirs.iter().map(|&d| (mf.abs_lambda(d), d.z < 0.0)).collect()
}

/// S_k of a direction sequence d_0..d_k with the complete invariance-principle
/// recursion (docs/paper-notes.md): O(k³) dynamic programming over sub-sequences.
/// One direction (k = 0) gives S_0 = 1; an empty slice gives 0.
pub fn segment_term(mf: &Microfacet, dirs: &[DVec3]) -> f64 {
    let n = dirs.len();
    if n == 0 {
        return 0.0;
    }
    let lam = lambdas(mf, dirs);
    // s[i*n + j] = S(d_i..d_j), j ≥ i.
    let mut s = vec![0.0f64; n * n];
    for i in 0..n {
        s[i * n + i] = 1.0;
    }
    for len in 1..n {
        for i in 0..n - len {
            let j = i + len;
            let (li, di) = lam[i];
            let (lj, dj) = lam[j];
            let c = s1(li, di, lj, !dj);
            if c == 0.0 {
                continue; // first up or last down: S = 0
            }
            let mut sum = 0.0;
            for l in i..j {
                sum += s[i * n + l] * s[(l + 1) * n + j];
            }
            s[i * n + j] = c * sum;
        }
    }
    s[n - 1]
}

/// The printed eq. 2 / Alg. 1 recursion S(i,j) = S_1(i,j)·(S(i+1,j) + S(i,j−1))
/// (S_1 alone for j = i+1): O(k²). Exact only for monotone sequences (no upward
/// direction later followed by a downward one), which every conductor path is.
pub fn segment_term_monotone(mf: &Microfacet, dirs: &[DVec3]) -> f64 {
    let n = dirs.len();
    if n == 0 {
        return 0.0;
    }
    if n == 1 {
        return 1.0;
    }
    let lam = lambdas(mf, dirs);
    // row[i] = S(i, j) for the current j; computed for j = 1..n−1.
    let mut prev = vec![0.0f64; n]; // S(i, j−1)
    let mut cur = vec![0.0f64; n];
    prev[0] = 1.0; // S(0,0)
    for j in 1..n {
        let (lj, dj) = lam[j];
        cur[j] = 1.0; // S(j,j)
        for i in (0..j).rev() {
            let (li, di) = lam[i];
            let c = s1(li, di, lj, !dj);
            cur[i] = if c == 0.0 {
                0.0
            } else if j == i + 1 {
                c
            } else {
                c * (cur[i + 1] + prev[i])
            };
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[0]
}

/// Bitterli & d'Eon 2022's p_exit (Cui supplement eq. 5 / Alg. 5 with |Λ|):
/// the height density after each vertex is kept as a sum of exponentials
/// Σ a_j e^{−b_j u} in u = −ln C(h). Exact in exact arithmetic (equals
/// (Π|Λ(d_i)|)·S_k), but a downward direction subtracts |Λ| values
/// (a_j ← a_j·L/(L − b_j)): cancellation, or division by zero when two
/// downward directions have the same |Λ|. A stability study, not a shipping path.
pub fn p_exit(mf: &Microfacet, dirs: &[DVec3]) -> f64 {
    p_exit_with_bound(mf, dirs).0
}

/// p_exit and a first-order bound on its absolute rounding error, from running
/// the same recursion on the magnitudes (unit roundoff u = 2⁻⁵³; L − b, the
/// quotient and the product each round once, a sum of N terms N times). The
/// relative bound (bound / |p_exit|) is ∞ at an exact division by zero.
pub fn p_exit_with_bound(mf: &Microfacet, dirs: &[DVec3]) -> (f64, f64) {
    const U: f64 = f64::EPSILON * 0.5;
    let n = dirs.len();
    if n < 2 {
        return (if n == 1 { 1.0 } else { 0.0 }, 0.0);
    }
    if dirs[0].z >= 0.0 || dirs[n - 1].z <= 0.0 {
        return (0.0, 0.0);
    }
    let l0 = mf.abs_lambda(dirs[0]);
    // (a_j, b_j, error bound of a_j)
    let mut a: Vec<f64> = vec![l0];
    let mut b: Vec<f64> = vec![l0];
    let mut e: Vec<f64> = vec![0.0];
    for &d in &dirs[1..n - 1] {
        if d.z < 0.0 {
            let l = mf.abs_lambda(d);
            let mut sum = 0.0;
            let mut sum_abs = 0.0;
            let mut sum_err = 0.0;
            for j in 0..a.len() {
                let f = l / (l - b[j]);
                let an = a[j] * f;
                e[j] = e[j] * f.abs() + 3.0 * U * an.abs();
                a[j] = an;
                sum += an;
                sum_abs += an.abs();
                sum_err += e[j];
            }
            let nn = a.len() as f64;
            a.push(-sum);
            b.push(l);
            e.push(sum_err + nn * U * sum_abs);
        } else {
            let lam = mf.lambda(d);
            for j in 0..a.len() {
                let f = lam / (b[j] + lam);
                a[j] *= f;
                e[j] = e[j] * f + 3.0 * U * a[j].abs();
            }
        }
    }
    let lk = mf.lambda(dirs[n - 1]);
    let mut p = 0.0;
    let mut abs = 0.0;
    let mut err = 0.0;
    for j in 0..a.len() {
        let t = a[j] / (b[j] + lk);
        p += t;
        abs += t.abs();
        err += (e[j] + 2.0 * U * a[j].abs()) / (b[j] + lk);
    }
    err += a.len() as f64 * U * abs;
    if !err.is_finite() {
        err = f64::INFINITY;
    }
    (p, err)
}

/// Relative error of Bitterli & d'Eon's p_exit ([`p_exit`]) against the stable
/// form (Π|Λ|)·S_k on conductor random-walk paths with `k` vertices from ω_i
/// (d_0 = −ω_i, each next direction a mirror reflection about a visible
/// normal, last direction upward): where the p_exit form cancels. Returns
/// (median relative error, largest finite one, fraction of non-finite results)
/// over the paths drawn (up to `n` attempts; paths that leave earlier or end
/// downward are skipped).
pub fn p_exit_error_study(mf: &Microfacet, wi: DVec3, k: usize, n: usize, rng: &mut Sampler) -> (f64, f64, f64) {
    let mut errors = Vec::with_capacity(n);
    let mut nonfinite = 0usize;
    for _ in 0..n {
        let mut dirs = vec![-wi];
        let mut w = wi;
        for _ in 0..k {
            let (u1, u2) = rng.next2();
            let Some(m) = mf.sample_visible(w, u1, u2) else { break };
            let d = reflect(w, m);
            dirs.push(d);
            w = -d;
        }
        if dirs.len() != k + 1 || dirs[k].z <= 0.0 {
            continue;
        }
        let reference = dirs[..k].iter().map(|&d| mf.abs_lambda(d)).product::<f64>() * segment_term(mf, &dirs);
        if !(reference > 0.0 && reference.is_finite()) {
            continue;
        }
        let p = p_exit(mf, &dirs);
        if p.is_finite() {
            errors.push(((p - reference) / reference).abs());
        } else {
            nonfinite += 1;
        }
    }
    let total = errors.len() + nonfinite;
    if total == 0 {
        return (0.0, 0.0, 0.0);
    }
    errors.sort_by(f64::total_cmp);
    let median = errors.get(errors.len() / 2).copied().unwrap_or(f64::INFINITY);
    let max = errors.last().copied().unwrap_or(f64::INFINITY);
    (median, max, nonfinite as f64 / total as f64)
}

/// Small growable buffer of f64 that stays on the stack for short paths.
#[derive(Clone)]
struct Buf {
    inline: [f64; 8],
    heap: Vec<f64>,
    len: usize,
}

impl Buf {
    fn new() -> Self {
        Buf { inline: [0.0; 8], heap: Vec::new(), len: 0 }
    }
    #[inline]
    fn push(&mut self, v: f64) {
        if self.len < self.inline.len() {
            self.inline[self.len] = v;
        } else {
            if self.heap.is_empty() {
                self.heap.extend_from_slice(&self.inline);
            }
            self.heap.push(v);
        }
        self.len += 1;
    }
    /// Sets the length to `n`, every value 0.
    fn fill_zero(&mut self, n: usize) {
        self.len = 0;
        self.heap.clear();
        for _ in 0..n {
            self.push(0.0);
        }
    }
    #[inline]
    fn as_slice(&self) -> &[f64] {
        if self.len <= self.inline.len() {
            &self.inline[..self.len]
        } else {
            &self.heap[..self.len]
        }
    }
    #[inline]
    fn as_mut_slice(&mut self) -> &mut [f64] {
        if self.len <= self.inline.len() {
            &mut self.inline[..self.len]
        } else {
            &mut self.heap[..self.len]
        }
    }
}

/// Incremental exit probabilities of a monotone path d_0..d_m (a downward
/// directions, then upward ones), the column form of the monotone recursion in
/// the module docs. The state is normalised by the hit probability H_m of the
/// history, so that the values stay O(1) for any path length:
/// `exit_given_hits(Λ)` = p_exit(d_0..d_m, x)/H_m for an upward x with Λ(x) = Λ.
///
/// For an upward x the column p(·, x) follows from the state by
/// c_a = p(a, x) (1 while the path is all downward: x follows d_{a−1}
/// directly; 0 once it went up, d_a pointing up) and, for i = a−1 down to 0,
///
/// c_i = (L_i·c_{i+1} + g_i)/(L_i + Λ(x)),   g_i = Λ(d_m)·p(i, m)/H_m
///
/// (the recursion's second term; g = 0 while the path is all downward).
/// With a single downward direction (the usual case) this is
/// L_0/(L_0 + Λ(x)) for every m: given that they hit, the upward segments leave
/// the height distribution of the first hit unchanged.
#[derive(Clone)]
pub struct MonotoneExit {
    /// L_i = |Λ(d_i)| of the downward directions d_0..d_{a−1}.
    down: Buf,
    /// g_i for i < a, valid once an upward direction was pushed.
    g: Buf,
    has_up: bool,
    /// H_m = probability that d_0..d_m all hit (product of the continuations).
    hit: f64,
}

impl MonotoneExit {
    /// Starts a path with d_0 (downward) of |Λ(d_0)| = `l0` (= 1 + Λ(ω_i)).
    pub fn new(l0: f64) -> Self {
        let mut down = Buf::new();
        down.push(l0);
        MonotoneExit { down, g: Buf::new(), has_up: false, hit: 1.0 }
    }

    /// Whether an upward direction has been pushed (a further downward one
    /// would make the path non-monotone).
    pub fn has_up(&self) -> bool {
        self.has_up
    }

    /// H_m: the probability that every direction pushed so far hits the surface.
    pub fn hit_probability(&self) -> f64 {
        self.hit
    }

    /// Appends a downward direction of |Λ| = `l` (≥ 1). Returns false (and
    /// does nothing) on a non-monotone path.
    pub fn push_down(&mut self, l: f64) -> bool {
        if self.has_up {
            return false;
        }
        self.down.push(l);
        true
    }

    /// c_0 of the column p(·, x)/H_m for a virtual upward x with Λ(x) = `lambda`.
    #[inline]
    fn column(&self, lambda: f64) -> f64 {
        let down = self.down.as_slice();
        if self.has_up {
            let g = self.g.as_slice();
            let mut c = 0.0;
            for i in (0..down.len()).rev() {
                c = (down[i] * c + g[i]) / (down[i] + lambda);
            }
            c
        } else {
            let mut c = 1.0;
            for &li in down.iter().rev() {
                c = li * c / (li + lambda);
            }
            c
        }
    }

    /// p_exit(d_0..d_m, x)/H_m: the probability that the path leaves along the
    /// upward x (Λ(x) = `lambda` ≥ 0) given that d_0..d_m all hit.
    #[inline]
    pub fn exit_given_hits(&self, lambda: f64) -> f64 {
        self.column(lambda)
    }

    /// p_exit(d_0..d_m, x) = (Π_{i≤m}|Λ(d_i)|)·S_{m+1}(d_0..d_m, x).
    pub fn exit_probability(&self, lambda: f64) -> f64 {
        self.hit * self.exit_given_hits(lambda)
    }

    /// p_exit(d_0..d_m, y, x)/H_m for a virtual downward y with |Λ(y)| = `l_y`
    /// followed by the upward x with Λ(x) = `lambda_x` (0 on a path that
    /// already went up: y would make it non-monotone).
    pub fn exit_via_down(&self, l_y: f64, lambda_x: f64) -> f64 {
        if self.has_up {
            return 0.0;
        }
        l_y / (l_y + lambda_x) * self.column(lambda_x)
    }

    /// p_exit(d_0..d_m, y, x)/H_m for a virtual upward y with Λ(y) = `lambda_y`
    /// followed by the upward x with Λ(x) = `lambda_x`: the two columns in one
    /// O(a) pass, nothing stored.
    pub fn exit_via_up(&self, lambda_y: f64, lambda_x: f64) -> f64 {
        let down = self.down.as_slice();
        let g = self.g.as_slice();
        let mut c_y = if self.has_up { 0.0 } else { 1.0 };
        let mut c_x = 0.0;
        for i in (0..down.len()).rev() {
            let li = down[i];
            let gi = if self.has_up { g[i] } else { 0.0 };
            c_y = (li * c_y + gi) / (li + lambda_y);
            c_x = (li * c_x + lambda_y * c_y) / (li + lambda_x);
        }
        c_x
    }

    /// Appends an upward direction with Λ = `lambda` (finite, ≥ 0) and returns
    /// the conditional probability H_{m+1}/H_m that it hits the surface again.
    pub fn push_up(&mut self, lambda: f64) -> f64 {
        let a = self.down.len;
        if !self.has_up {
            self.g.fill_zero(a);
        }
        let down = self.down.as_slice();
        let g = self.g.as_mut_slice();
        // One pass: the new column c_i = p(i, m+1)/H_m (g ← Λ·c_i) and
        // H_{m+1}/H_m = p(0, ẑ)/H_m with the new last direction (Λ(ẑ) = 0),
        // whose column is z_i = z_{i+1} + Λ·c_i/L_i, z_a = 0.
        let mut c = if self.has_up { 0.0 } else { 1.0 };
        let mut cont = 0.0;
        for i in (0..a).rev() {
            let li = down[i];
            c = (li * c + g[i]) / (li + lambda);
            g[i] = lambda * c;
            cont += g[i] / li;
        }
        self.has_up = true;
        if cont > 0.0 && cont.is_finite() {
            let r = 1.0 / cont;
            for v in g.iter_mut() {
                *v *= r;
            }
            self.hit *= cont;
        } else {
            self.hit = 0.0;
        }
        cont
    }
}

/// First vertex after whose NEE Russian roulette may end a walk.
const RR_START: u32 = 1;

/// Throughput (largest channel) above which the walk of `eval` surely goes on.
/// Below it the roulette keeps the walk with probability throughput/RR_KEEP,
/// so a survivor carries weight RR_KEEP. Heitz's rule (keep with probability
/// equal to the throughput, RR_KEEP = 1) ends too many of the walks that can
/// still reach ω_o once those that cannot are stopped exactly (see `eval`):
/// at GGX α = 1, 1/2 lowers the variance per call by 6 % (off-specular) and
/// 13 % (mirror) for ≈ 5 % more time.
const RR_KEEP: f64 = 0.5;


/// Highest order estimated by the connection as well as by the walk's NEE.
/// Beyond it the NEE alone is better: at GGX α = 1 off-specular, connecting
/// at every order raises the variance per call by 4 % (the shared y
/// correlates the orders) and costs a D, a Fresnel term and an O(a) exit
/// probability per vertex. Order 3 still pays (−8 % variance for ≈ 5 % time).
const CONNECT_MAX_ORDER: u32 = 3;


/// One unbiased estimate of f(ω_i, ω_o)·cos θ_o of the invariance model,
/// restricted to the orders `opts.orders` and at most `opts.max_bounces`
/// vertices (`opts.segments` is ignored). Order 1 is deterministic:
/// F·D·G2/(4 cos θ_i) with G2 = 1/(1 + Λ(ω_i) + Λ(ω_o)).
///
/// Orders 2 ≤ k ≤ `CONNECT_MAX_ORDER` (3) combine two strategies for the last
/// inner direction d_{k−1} with the balance heuristic: the walk's own sample
/// (visible normals of −d_{k−2}, closed by NEE at vertex k−1) and a connection
/// from vertex k−2 to d_{k−1} = y = −(ω_o reflected about a visible normal of
/// ω_o). Both are closed forms thanks to the position-free path contribution;
/// the second removes most of the variance off-specular, where the NEE phase
/// value at the last vertex peaks (order-2 variance ÷2.5–4 at GGX α = 0.5–1).
///
/// One y serves both connected orders (`LightVertex`): each order's connection is
/// unbiased for any y drawn from its density, independently of the walk, so
/// reusing it only correlates the orders. A fresh y per connection lowers the
/// variance by ≈ 6 % (GGX α = 1, off-specular) for ≈ 15–30 % more time per call
/// (a visible-normal sample, a D, a Λ and a Fresnel term each).
pub fn eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    if !(wi.z > 0.0) || !(wo.z > 0.0) || !wi.is_finite() || !wo.is_finite() {
        return Spectrum::ZERO;
    }
    let last = opts.orders.1.min(opts.max_bounces);
    if last == 0 || opts.orders.0 > last {
        return Spectrum::ZERO;
    }
    let lambda_o = mf.lambda(wo);
    if !lambda_o.is_finite() {
        return Spectrum::ZERO;
    }
    let area_o = wo.z * (1.0 + lambda_o); // A(ω_o)
    let pdf_scale_o = 0.25 / area_o;
    // The connection strategy serves orders 2..=CONNECT_MAX_ORDER.
    let connects = last >= 2 && opts.orders.0 <= CONNECT_MAX_ORDER;
    let light = if connects { LightVertex::sample(mf, fresnel, wo, pdf_scale_o, rng) } else { None };
    let l0 = mf.abs_lambda(-wi);
    // w = −d_m, and 1/(4 A(w)) with its projected area A(w) = |cos d_m|·|Λ(d_m)|:
    // reflect_pdf(w, x) = D(h)/(4 A(w)) for every x the vertex scatters into
    // (ω_o for the NEE, y for the connection, the walk's own sample).
    let mut w = wi;
    let mut pdf_scale = 0.25 / (wi.z * l0);
    // Density with which the walk sampled d_m from −d_{m−1} (the forward
    // strategy's density in the MIS weight of the NEE at vertex m ≥ 1).
    let mut pdf_walk = 0.0;
    let mut dp = MonotoneExit::new(l0);
    let mut throughput = Spectrum::ONE; // Π F · Π (H_j/H_{j−1}) / Π q
    let mut result = Spectrum::ZERO;
    for j in 0..last {
        let order = j + 1;
        if order >= opts.orders.0 {
            // NEE: v_m/L_m = D(h)/(4 A(−d_m)) = reflect_pdf(w, ω_o).
            let (d_h, cos_wh) = half_vector_d(mf, w, wo);
            let mut value = d_h * pdf_scale;
            if j > 0 && order <= CONNECT_MAX_ORDER && value > 0.0 {
                // Balance heuristic against the connection, which samples
                // y = d_m as reflect_pdf(ω_o, −d_m): the same half vector,
                // D(h)/(4 A(ω_o)). (The power heuristic lowers the variance
                // by 2 % at GGX α = 1 off-specular and raises it by 8 % at
                // α = 0.5 grazing.)
                let p_rev = d_h * pdf_scale_o;
                value *= pdf_walk / (pdf_walk + p_rev);
            }
            if value > 0.0 && value.is_finite() {
                value *= dp.exit_given_hits(lambda_o);
                result += throughput * fresnel.eval(cos_wh) * value;
            }
        }
        if order >= last {
            break;
        }
        // Connection strategy for order + 1: d_{m+1} = y from the side of ω_o.
        if order + 1 >= opts.orders.0 && order < CONNECT_MAX_ORDER {
            if let Some(light) = &light {
                result += throughput * light.connect(mf, fresnel, &dp, w, pdf_scale, lambda_o);
            }
        }
        // Russian roulette on the weight carried so far (Π F · H_m), played
        // after the estimates of this vertex: they always see the continuous
        // hit probability (a near-vertical upward d_m hits with probability
        // ∝ Λ(d_m) while its NEE phase value ∝ 1/Λ(d_m); a binary decision
        // before the NEE multiplies the variance of order 2 ≈ 2×).
        if j >= RR_START && !russian_roulette_keep(&mut throughput, rng, RR_KEEP) {
            break;
        }
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(w, u1, u2) else { break };
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            break;
        }
        let d_next = reflect(w, m);
        // Along the upward run z only grows (module docs: d'.z > d.z for every
        // front-facing facet, and exactly so in floating point:
        // d'.z = d.z + 2(w·m)m.z with w·m, m.z > 0). Once an upward d.z ≥ ω_o.z
        // no later vertex can reach ω_o: the NEE's half vector has
        // h.z ∝ ω_o.z − d.z ≤ 0 (D = 0), and the connection's y has
        // y.z ≤ ω_o.z ≤ d.z (D = 0 again, or a downward y after an upward
        // direction: non-monotone). Every further estimate is exactly 0.
        let up = d_next.z > 0.0;
        if up && d_next.z >= wo.z {
            break;
        }
        throughput *= fresnel.eval(cos_wm);
        // m is the half vector of w and d_next: density D(m)/(4 A(w)), needed
        // by the MIS weight of the next NEE while the connection serves it.
        if order < CONNECT_MAX_ORDER {
            pdf_walk = mf.d(m) * pdf_scale;
        }
        let l_next;
        if up {
            l_next = mf.lambda(d_next);
            if !l_next.is_finite() {
                break;
            }
            let cont = dp.push_up(l_next);
            throughput *= cont;
            if !(cont > 0.0) || !(throughput.max_value() > 0.0) {
                break;
            }
        } else {
            l_next = mf.abs_lambda(d_next);
            if !l_next.is_finite() || !dp.push_down(l_next) {
                break;
            }
        }
        w = -d_next;
        pdf_scale = 0.25 / (d_next.z.abs() * l_next);
    }
    result
}

/// (D(h), w·h) for the half vector h of w and x; (0, 0) when w does not see h.
#[inline]
fn half_vector_d(mf: &Microfacet, w: DVec3, x: DVec3) -> (f64, f64) {
    let h = w + x;
    let len = h.length();
    if !(len > 0.0) {
        return (0.0, 0.0);
    }
    let h = h * (1.0 / len);
    let c = w.dot(h);
    if !(c > 0.0) {
        return (0.0, 0.0);
    }
    (mf.d(h), c)
}

/// The one-vertex light subpath of the connection strategy: y = −(ω_o
/// reflected about a visible normal m of ω_o), with everything about it that
/// does not depend on the walk.
struct LightVertex {
    y: DVec3,
    /// |Λ(y)|, and whether y points up.
    l_y: f64,
    up: bool,
    /// Density of y: reflect_pdf(ω_o, −y) = D(m)/(4 A(ω_o)).
    pdf: f64,
    /// reflect_pdf(−y, ω_o) = D(m)/(4 A(−y)): the last vertex's phase value.
    phase: f64,
    /// F(ω_o·m) at the last vertex.
    fresnel: Spectrum,
}

impl LightVertex {
    /// `pdf_scale_o` = 1/(4 A(ω_o)).
    fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, wo: DVec3, pdf_scale_o: f64, rng: &mut Sampler) -> Option<Self> {
        let (u1, u2) = rng.next2();
        let m = mf.sample_visible(wo, u1, u2)?;
        let cos1 = wo.dot(m);
        if !(cos1 > 0.0) {
            return None;
        }
        let y = -reflect(wo, m);
        let up = y.z > 0.0;
        let l_y = if up { mf.lambda(y) } else { mf.abs_lambda(y) };
        let area_y = y.z.abs() * l_y; // A(−y)
        let d_m = mf.d(m);
        let (pdf, phase) = (d_m * pdf_scale_o, 0.25 * d_m / area_y);
        if !(pdf > 0.0) || !(phase > 0.0) || !pdf.is_finite() || !phase.is_finite() || !l_y.is_finite() {
            return None;
        }
        Some(LightVertex { y, l_y, up, pdf, phase, fresnel: fresnel.eval(cos1) })
    }

    /// The connection estimate at vertex m (w = −d_m, `pdf_scale` = 1/(4 A(w))): the path
    /// d_0..d_m, y, ω_o weighted by the balance heuristic against the walk
    /// sampling y from the visible normals of w, divided by the density of
    /// d_1..d_m and by H_m (the caller multiplies by its throughput).
    fn connect(&self, mf: &Microfacet, fresnel: &ConductorFresnel, dp: &MonotoneExit, w: DVec3, pdf_scale: f64, lambda_o: f64) -> Spectrum {
        let (d_h, cos0) = half_vector_d(mf, w, self.y);
        let p_fwd = d_h * pdf_scale; // reflect_pdf(w, y): the walk's density of y
        if !(p_fwd > 0.0) || !p_fwd.is_finite() {
            return Spectrum::ZERO;
        }
        let exit = if self.up { dp.exit_via_up(self.l_y, lambda_o) } else { dp.exit_via_down(self.l_y, lambda_o) };
        // F_m F_y · reflect_pdf(w, y)·reflect_pdf(−y, ω_o)·exit / p_y, times
        // the balance heuristic p_y/(p_fwd + p_y) against the walk.
        let value = p_fwd * self.phase * exit / (p_fwd + self.pdf);
        if !(value > 0.0) || !value.is_finite() {
            return Spectrum::ZERO;
        }
        fresnel.eval(cos0) * self.fresnel * value
    }
}

/// Random-walk sampling of the invariance model: reflect about visible normals
/// and, at each upward direction d_m, leave with probability 1 − H_m/H_{m−1}
/// (the exact conditional exit probability of the heights-integrated walk).
/// The density of the sampled ω_o and order is then the path contribution over
/// Π F, so the weight is Π F (≤ 1 per channel, no roulette needed).
/// `first` = (u_exit, u1, u2) drives the first vertex. Returns None when the
/// walk needs more than min(max_bounces, orders.1) vertices, leaves before
/// orders.0, or meets a degenerate direction — the same truncation as `eval`,
/// so E[weight·g(ω_o)] = ∫ g·eval.
pub fn sample(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if !(wi.z > 0.0) || !wi.is_finite() {
        return None;
    }
    let last = opts.orders.1.min(opts.max_bounces);
    if last == 0 || opts.orders.0 > last {
        return None;
    }
    let mut w = wi;
    let mut dp = MonotoneExit::new(mf.abs_lambda(-wi));
    let mut weight = Spectrum::ONE;
    for j in 0..last {
        let (u_exit, u1, u2) = vertex_numbers(j, first, rng);
        let m = mf.sample_visible(w, u1, u2)?;
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            return None;
        }
        let d_next = reflect(w, m);
        weight *= fresnel.eval(cos_wm);
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            if !lambda.is_finite() {
                return None;
            }
            let cont = dp.push_up(lambda);
            if u_exit >= cont {
                let order = j + 1;
                if order < opts.orders.0 || !d_next.is_finite() {
                    return None;
                }
                return Some((d_next, weight, order));
            }
        } else {
            let l = mf.abs_lambda(d_next);
            if !l.is_finite() || !dp.push_down(l) {
                return None;
            }
        }
        w = -d_next;
    }
    None
}
