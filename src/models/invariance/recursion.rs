//! Multiple-bounce Smith microfacet BRDF from the invariance principle,
//! Cui et al. 2023: the segment term S_k and the exit probability, with the
//! corrected readings of docs/paper-notes.md.
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

use crate::microfacet::{reflect, Microfacet};
use crate::rng::Sampler;
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
