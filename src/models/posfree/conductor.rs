//! Position-free multiple scattering on specular conductor facets (Wang et
//! al. 2022 §3, eqs. 1–2, 7–11, 17–18): the PT estimator with next-event
//! estimation, the random-walk sampler and the vertex terms of the
//! bidirectional estimator (`walk/bdpt.rs`). The pair factors of the segment
//! models are in `mod.rs`.

use super::{roulette_importance, Options, Segments};
use crate::microfacet::ConductorFresnel;
use crate::microfacet::Microfacet;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use crate::walk::{bdpt, russian_roulette_keep, sample_conductor, ConductorExit, RR_START};
use glam::DVec3;

/// PT estimator with next-event estimation towards ω_o at every vertex
/// (Wang eqs. 24–26). Returns one sample of f(ω_i, ω_o)·cos θ_o: Wang's vertex
/// term carries 1/(4|cos θ_i|) only, so the path integral ρ is already cosine-weighted.
///
/// The model is defined on the whole sphere of incident directions (Wang
/// 2022 §5, normal mapping): ω_i below the macro surface (a tilted shading
/// normal) starts the walk with an upward d_0 = −ω_i, whose L_0 = Λ(d_0) is
/// the projected-area factor of ω_i's visible normals there, as at any
/// vertex reached by an upward segment. ω_o must point up (light leaves
/// upward only).
pub fn eval_pt(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> Spectrum {
    if wi.z == 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    // Vertex 0: light arrives from ω_i, L_0 = |Λ(d_0)| = |Λ(−ω_i)| (1 + Λ(ω_i) for ω_i above).
    let start = PtState { w: wi, l: mf.abs_lambda(-wi), throughput: Spectrum::ONE };
    let orders = opts.walk.clamped_orders();
    pt_walk(mf, fresnel, wo, mf.lambda(wo), opts.segments, start, 0, orders, RR_START, rng)
}

/// A PT walk arriving at a vertex: `w` = −d_j (where the light comes from, seen
/// from the vertex), `l` = L_j = |Λ(d_j)|, and the throughput f/pdf of the prefix.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PtState {
    pub w: DVec3,
    pub l: f64,
    pub throughput: Spectrum,
}

/// Gain of the next-event value in [`roulette_importance`] for conductors.
/// Measured (GGX α ∈ {0.2, 0.5, 1}, Cu, fixed and random pairs, efficiency
/// 1/(variance·time)): 30 within 5 % of the best gain of {10, 30, 100} in
/// every case; 10 loses up to 25 % at α = 1, 100 up to 10 % at α = 0.2.
pub(crate) const RR_NEE_GAIN: f64 = 30.0;

/// The conductor's next-event term at a vertex with w = −d_j and last-segment
/// factor `last`, without the Fresnel factor: (w·h, D(h)·last/(4|w_z|)) with h
/// the half vector of w and ω_o, or None when ω_o cannot be reached by reflection.
#[inline]
fn nee_term(mf: &Microfacet, w: DVec3, wo: DVec3, last: f64) -> Option<(f64, f64)> {
    let h = w + wo;
    let len = h.length();
    if len > 0.0 {
        let h = h / len;
        let cos_wh = w.dot(h);
        if cos_wh > 0.0 && wo.dot(h) > 0.0 {
            return Some((cos_wh, mf.d(h) * last / (4.0 * w.z.abs())));
        }
    }
    None
}

/// The PT-with-NEE walk from vertex `first_vertex` (0-based) on: at each
/// vertex ≥ `rr_start` play Russian roulette on the importance of the vertex
/// (its next-event value included), close the path towards ω_o when its order
/// is within `orders`, then sample the next direction from the visible
/// normals and multiply the Fresnel term and the continue factor. Shared by
/// `eval_pt` and the PT tail of the BDPT estimators.
#[allow(clippy::too_many_arguments)]
pub(crate) fn pt_walk(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wo: DVec3,
    lambda_o: f64,
    segments: Segments,
    state: PtState,
    first_vertex: u32,
    orders: (u32, u32),
    rr_start: u32,
    rng: &mut Sampler,
) -> Spectrum {
    let PtState { mut w, mut l, mut throughput } = state;
    let mut result = Spectrum::ZERO;
    for j in first_vertex..orders.1 {
        // L = 0 (the walk left for sure; p_j = 1/L_j would divide by zero), a
        // horizontal direction (p_j = 0), or nothing left to carry.
        if !(l > 0.0) || !l.is_finite() || !(throughput.max_value() > 0.0) {
            break;
        }
        let order = j + 1;
        let last = segments.last(l, lambda_o);
        let nee = if order >= orders.0 { nee_term(mf, w, wo, last) } else { None };
        if j >= rr_start {
            let importance = roulette_importance(nee.map_or(0.0, |(_, v)| v), last, RR_NEE_GAIN);
            if !russian_roulette_keep(&mut throughput, rng, 1.0 / importance) {
                break;
            }
        }
        // Next-event estimation: close the path towards ω_o at this vertex.
        if let Some((cos_wh, value)) = nee {
            result += throughput * fresnel.eval(cos_wh) * value;
        }
        if order >= orders.1 {
            break;
        }
        // Sample the next direction from the visible normals of w.
        let (u1, u2) = rng.next2();
        let Some((_, cos_wm, d_next)) = mf.reflect_visible(w, u1, u2) else { break };
        throughput *= fresnel.eval(cos_wm);
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            throughput *= segments.continue_up(l, lambda);
            l = lambda;
        } else {
            l = mf.abs_lambda(d_next);
        }
        w = -d_next;
    }
    result
}

/// Random-walk sampler (Wang §4.3 with the exit probabilities of docs/paper-notes.md):
/// at each upward direction the walk leaves with probability 1 − continue_up
/// ([`walk::sample_conductor`](crate::walk::sample_conductor)), so that the
/// weight is the product of the Fresnel terms. The first vertex uses the
/// caller's (u_exit, u1, u2). Returns (ω_o, weight, order) or None.
pub fn sample_walk(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &Options,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if wi.z == 0.0 {
        return None;
    }
    // As in eval_pt: ω_i may lie below the macro surface.
    let mut exit = SegmentExit { segments: opts.segments, l: mf.abs_lambda(-wi) };
    sample_conductor(mf, fresnel, wi, first, opts.walk.max_bounces, &mut exit, rng)
}

/// The position-free exit: the segment term's continuation probability from
/// the last segment's |Λ| `l`.
struct SegmentExit {
    segments: Segments,
    l: f64,
}

impl ConductorExit for SegmentExit {
    fn up(&mut self, lambda: f64) -> Option<f64> {
        let p_continue = self.segments.continue_up(self.l, lambda);
        self.l = lambda;
        Some(p_continue)
    }

    fn down(&mut self, l: f64) -> bool {
        self.l = l;
        true
    }
}

// ---------------------------------------------------------------------------
// The bidirectional estimator (Wang 2022 §4.2, eqs. 27–29; src/walk/bdpt.rs).
//
// With L_j = |Λ(d_j)| and the pair factors of `mod.rs`, eq. 1 factors into
// one term per vertex j, each depending on the two directions around it only:
//
//   f = Π_{j=0}^{k−1} φ_j(d_j, d_{j+1}),
//   φ_j = F_j·D(h_j)/(4|cos d_j|) · g_j,    h_j = normalize(−d_j + d_{j+1}),
//   g_j = cont(L_j, d_{j+1})/L_j   (j < k−1;  cont = Segments::continue_up for
//                                   an upward d_{j+1}, 1 for a downward one)
//   g_{k−1} = Segments::last(L_{k−1}, Λ(ω_o)).
//
// Sampling densities (solid angle), with A(ω) = ∫⟨ω,m⟩D(m)dm the projected
// area (A(−d_j) = |cos d_j|·L_j):
// - camera step at vertex j: m ~ D_{−d_j}, d_{j+1} = reflect(−d_j, m):
//   pf_j = D_{−d_j}(h_j)/(4⟨−d_j,h_j⟩) = D(h_j) / (4 A(−d_j)), so φ_j/pf_j = F_j·cont;
// - light step at vertex j: m ~ D_{d_{j+1}}, −d_j = reflect(d_{j+1}, m):
//   pr_j = D(h_j) / (4 A(d_{j+1})) (the sign flip d ↦ −d preserves solid angle),
//   so φ_j/pr_j = F_j·A(d_{j+1})·g_j/|cos d_j| (D cancels).

/// Smith quantities of a direction d from one Λ evaluation:
/// (L = |Λ(d)|, A(d), A(−d)), with A(d) = |cos d|·|Λ(−d)| and A(−d) = |cos d|·L.
/// Λ of the upward direction with the same slope, u ≥ 0, gives |Λ(d)| = u
/// (d up) or 1 + u (d down) without cancellation (docs/paper-notes.md).
#[inline]
pub(crate) fn smith(mf: &Microfacet, d: DVec3) -> (f64, f64, f64) {
    let u = mf.lambda(DVec3::new(d.x, d.y, d.z.abs()));
    let c = d.z.abs();
    if d.z >= 0.0 {
        (u, c * (1.0 + u), c * u)
    } else {
        (1.0 + u, c * u, c * (1.0 + u))
    }
}

/// g_j · L_j for a middle vertex: the continue factor of the next direction.
#[inline]
pub(crate) fn cont(seg: Segments, l: f64, next: DVec3, l_next: f64) -> f64 {
    if next.z > 0.0 {
        seg.continue_up(l, l_next)
    } else {
        1.0
    }
}

/// A camera vertex: d_s, L_s, A(−d_s) and the prefix f/p (Π F·cont).
#[derive(Clone, Copy, Default)]
pub(crate) struct CamVertex {
    pub d: DVec3,
    pub l: f64,
    pub area_back: f64,
    pub thr: Spectrum,
}

/// A light vertex: e_t = d_{k−t}, |Λ(e_t)|, A(e_t) and Π φ/pr of its t steps.
#[derive(Clone, Copy, Default)]
pub(crate) struct LightVertex {
    pub e: DVec3,
    pub l: f64,
    pub area: f64,
    pub w: Spectrum,
}

/// The segment term of a conductor path as the bidirectional estimator uses
/// it. Wang's models factor it into pair factors along the path (`Segments`:
/// the continue factor of every middle vertex, the last segment's factor);
/// a model whose segment term belongs to the whole path (Cui 2023's S_k,
/// src/models/invariance/conductor.rs) sets the pair factors to the bare
/// 1/L_j and supplies the whole path's factor at each connection. The PT tail
/// above K_b is the model's own walk.
pub(crate) trait ConductorSegments {
    /// g_j·L_j of a middle vertex: what the path keeps of the segment from
    /// light arriving with |Λ| = `l` to `next` (|Λ(next)| = `l_next`).
    fn cont(&self, l: f64, next: DVec3, l_next: f64) -> f64;
    /// p_{k−1}·e_k of the last vertex towards ω_o (Λ(ω_o) = `lambda_o`).
    fn last(&self, l: f64, lambda_o: f64) -> f64;
    /// The factor of the whole path d_0..d_s (`cam`), e_t..e_0 (`light`) at a
    /// connection; None when the path cannot exist.
    fn whole_path(&self, _cam: &[CamVertex], _light: &[LightVertex], _lambda_o: f64) -> Option<f64> {
        Some(1.0)
    }
    /// The model's PT estimate of the orders above K_b from the end of `cam`.
    fn pt_tail(&self, to: Outgoing, cam: &[CamVertex], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum;
}

/// What a PT tail reads besides the camera subpath: the microsurface, its
/// Fresnel term, ω_o and Λ(ω_o).
#[derive(Clone, Copy)]
pub(crate) struct Outgoing<'a> {
    pub mf: &'a Microfacet,
    pub fresnel: &'a ConductorFresnel,
    pub wo: DVec3,
    pub lambda_o: f64,
}

impl ConductorSegments for Segments {
    #[inline]
    fn cont(&self, l: f64, next: DVec3, l_next: f64) -> f64 {
        cont(*self, l, next, l_next)
    }

    #[inline]
    fn last(&self, l: f64, lambda_o: f64) -> f64 {
        Segments::last(*self, l, lambda_o)
    }

    fn pt_tail(&self, to: Outgoing, cam: &[CamVertex], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let cv = &cam[kb as usize];
        let state = PtState { w: -cv.d, l: cv.l, throughput: cv.thr };
        pt_walk(to.mf, to.fresnel, to.wo, to.lambda_o, *self, state, kb, orders, kb + RR_START, rng)
    }
}

/// The conductor's vertex terms for `walk::bdpt`, with the segment term `seg`.
struct Bidirectional<'a, S: ConductorSegments> {
    mf: &'a Microfacet,
    fresnel: &'a ConductorFresnel,
    seg: &'a S,
    wi: DVec3,
    wo: DVec3,
    lambda_o: f64,
}

impl<S: ConductorSegments> Bidirectional<'_, S> {
    /// g_j of the vertex between an arriving direction with |Λ| = `l` and the
    /// next direction `next` (|Λ(next)| = `l_next`; ω_o when `last`).
    #[inline]
    fn g(&self, l: f64, next: DVec3, l_next: f64, last: bool) -> f64 {
        if last {
            self.seg.last(l, self.lambda_o)
        } else {
            self.seg.cont(l, next, l_next) / l
        }
    }
}

impl<S: ConductorSegments> bdpt::BdptSurface for Bidirectional<'_, S> {
    type Cam = CamVertex;
    type Light = LightVertex;
    /// φ_s and the cosine of the connecting facet.
    type Conn = (f64, f64);
    type Value = Spectrum;

    fn camera_start(&self) -> CamVertex {
        let l0 = 1.0 + self.mf.lambda(self.wi);
        CamVertex { d: -self.wi, l: l0, area_back: self.mf.projected_area(self.wi), thr: Spectrum::ONE }
    }

    fn camera_ready(&self, v: &CamVertex) -> bool {
        v.l > 0.0 && v.l.is_finite() && v.area_back > 0.0
    }

    fn camera_step(&self, v: &mut CamVertex, s: usize, rng: &mut Sampler) -> Option<bdpt::Step<CamVertex>> {
        let w = -v.d;
        let (u1, u2) = rng.next2();
        let (m, cos_wm, d_next) = self.mf.reflect_visible(w, u1, u2)?;
        let (l_next, area_next, area_back_next) = smith(self.mf, d_next);
        let dm = self.mf.d(m);
        let pf = dm / (4.0 * v.area_back);
        if !(pf > 0.0) || !pf.is_finite() || !(area_next > 0.0) {
            return None;
        }
        let p_rev = if s >= 1 { dm / (4.0 * area_next) } else { 0.0 };
        let thr = v.thr * self.fresnel.eval(cos_wm) * self.seg.cont(v.l, d_next, l_next);
        Some(bdpt::Step { vertex: CamVertex { d: d_next, l: l_next, area_back: area_back_next, thr }, p_in: pf, p_rev })
    }

    fn light_start(&self) -> LightVertex {
        LightVertex { e: self.wo, l: self.lambda_o, area: self.mf.projected_area(self.wo), w: Spectrum::ONE }
    }

    fn light_ready(&self, v: &LightVertex) -> bool {
        v.area > 0.0 && v.area.is_finite()
    }

    fn light_step(&self, v: &LightVertex, t: usize, rng: &mut Sampler) -> Option<bdpt::Step<LightVertex>> {
        let (u1, u2) = rng.next2();
        let (m, cos_em, reflected) = self.mf.reflect_visible(v.e, u1, u2)?;
        let e_next = -reflected; // d_j, arriving at vertex j = k−1−t
        let (l_next, area_next, area_back_next) = smith(self.mf, e_next);
        let cos_next = e_next.z.abs();
        if !(l_next > 0.0) || !l_next.is_finite() || !(cos_next > 0.0) {
            return None;
        }
        let dm = self.mf.d(m);
        let pr = dm / (4.0 * v.area);
        if !(pr > 0.0) || !pr.is_finite() || !(area_back_next > 0.0) {
            return None;
        }
        // φ_j / pr_j = F·A(d_{j+1})·g_j / |cos d_j|.
        let g = self.g(l_next, v.e, v.l, t == 0);
        let w = v.w * self.fresnel.eval(cos_em) * (v.area * g / cos_next);
        let p_rev = if t >= 1 { dm / (4.0 * area_back_next) } else { 0.0 };
        Some(bdpt::Step { vertex: LightVertex { e: e_next, l: l_next, area: area_next, w }, p_in: pr, p_rev })
    }

    fn connect(&self, cam: &[CamVertex], light: &[LightVertex]) -> Option<bdpt::Connection<(f64, f64)>> {
        let (s, t) = (cam.len() - 1, light.len() - 1);
        let (cv, lv) = (&cam[s], &light[t]);
        if !(cv.thr.max_value() > 0.0) || !(lv.w.max_value() > 0.0) {
            return None;
        }
        let cos_s = cv.d.z.abs();
        if !(cv.l > 0.0) || !cv.l.is_finite() || !(cos_s > 0.0) || !(lv.area > 0.0) {
            return None;
        }
        let h = -cv.d + lv.e;
        let len = h.length();
        if !(len > 0.0) {
            return None;
        }
        let h = h / len;
        let cos_h = -cv.d.dot(h);
        if h.z <= 0.0 || cos_h <= 0.0 {
            return None;
        }
        let dh = self.mf.d(h);
        if !(dh > 0.0) {
            return None;
        }
        let phi = dh * self.g(cv.l, lv.e, lv.l, t == 0) / (4.0 * cos_s) * self.seg.whole_path(cam, light, self.lambda_o)?;
        let pr = if s >= 1 { dh / (4.0 * lv.area) } else { 0.0 };
        let pf = if t >= 1 { dh / (4.0 * cv.area_back) } else { 0.0 };
        Some(bdpt::Connection { pr, pf, data: (phi, cos_h) })
    }

    fn weighted(&self, conn: &bdpt::Connection<(f64, f64)>, cv: &CamVertex, lv: &LightVertex, denom: f64) -> Option<Spectrum> {
        let (phi, cos_h) = conn.data;
        let weight = phi / denom;
        weight.is_finite().then(|| cv.thr * lv.w * self.fresnel.eval(cos_h) * weight)
    }

    fn pt_tail(&self, cam: &[CamVertex], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let to = Outgoing { mf: self.mf, fresnel: self.fresnel, wo: self.wo, lambda_o: self.lambda_o };
        self.seg.pt_tail(to, cam, kb, orders, rng)
    }
}

/// BDPT estimate of f(ω_i, ω_o)·cos θ_o with the default number of
/// bidirectional orders ([`bdpt::DEFAULT_BDPT_ORDERS`]).
pub fn eval_bdpt(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> Spectrum {
    eval_bdpt_with(mf, fresnel, wi, wo, opts, bdpt::DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`bdpt::MAX_BDPT_ORDERS`]) and higher orders by path tracing.
pub fn eval_bdpt_with(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    wo: DVec3,
    opts: &Options,
    bdpt_orders: u32,
    rng: &mut Sampler,
) -> Spectrum {
    if wi.z < 0.0 && wo.z > 0.0 {
        // ω_i below the macro surface (normal mapping): the PT estimator, which covers it (same expectation).
        return eval_pt(mf, fresnel, wi, wo, opts, rng);
    }
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    estimate_bdpt(mf, fresnel, &opts.segments, wi, wo, &opts.walk, bdpt_orders, rng)
}

/// The bidirectional estimate of a conductor with the segment term `seg`
/// (ω_i and ω_o above the surface), orders `opts.walk.orders`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn estimate_bdpt<S: ConductorSegments>(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    seg: &S,
    wi: DVec3,
    wo: DVec3,
    opts: &WalkOptions,
    bdpt_orders: u32,
    rng: &mut Sampler,
) -> Spectrum {
    let surface = Bidirectional { mf, fresnel, seg, wi, wo, lambda_o: mf.lambda(wo) };
    bdpt::estimate(&surface, opts.clamped_orders(), bdpt_orders, rng)
}
