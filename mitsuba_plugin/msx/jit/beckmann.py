"""Beckmann specifics of the Dr.Jit engine: twin of ``src/microfacet/beckmann.rs`` (its special functions,
erfc, erfcx and norm_inv, are in ``special.py``): Λ through erfc without the 1 + erf cancellation, and
visible-normal sampling for stretched (α = 1) incident directions on the whole sphere.

Same names as the Rust functions (``lambda_up``, ``sample_visible_std``, ``sample_slope_x``,
``newton_monotone``). Everything is traced float32 Dr.Jit code in
variant-agnostic types (mi.Float, mi.Vector3f): branches are masks, Newton runs a fixed number of unrolled
iterations, nothing is read back to Python.

What differs from the Rust (float64) code:

* **Below the horizon** the Rust inverts ln G(x) = −x² + ln b(x) in x. In float32, x² ≈ t² is huge for
  steep directions while the distribution of s = t − x has width ~1/|t|, so Newton runs in v = x − t = −s
  on ln G(x) − ln G(t) = −s(s + 2|t|) + ln(b(x)/b(t)), with b(x) = d(z) + (1 − d(z))·s/z, z = −x
  (all terms positive: no cancellation).
* **Above the horizon** the Rust solves G(x) = u·G(hi). Here Newton runs on the same root of
  √(ln G(hi) − ln G(x)) − √(−ln u), with ln G evaluated without underflow: that function is nearly linear
  in x over the whole range (exactly so at θ = π/2, where G ∝ e^{−x²}; like |x| in the Gaussian tail,
  like t − x near the truncation at t), so the iteration count is uniform in u, whereas on G itself Newton
  crawls through the tails (steps ~1/(2|x|)) and, from the float32-clamped Gaussian guess, needs tens of
  iterations for u → 0. Where the Rust's initial guess lies beyond t (u → 1), the guess comes from the
  density's linear vanishing at t instead; below the horizon the Rust's guesses are kept except for
  u → 1 (−ln u < 0.1), where s ≈ √(−b(t)·ln u) is the exact limit.
* **Newton / Halley** (``newton_monotone``) runs at most ``NEWTON_ITERATIONS`` = 12 iterations with the
  bracket kept per lane. Above the horizon (and below it where −ln u ≥ ``HALLEY_MIN_L`` = 0.1) the step
  is Halley's, with f'' in closed form from f' ((ln G)'' = (ln G)'·(−1/(t − x) − 2x) − (ln G)'², no new
  special function); below it for u → 1 it stays Newton's (Halley's correction is ill-conditioned where
  f' → 0 at s → 0: with Halley there the worst lane below went from 5.66 to 6.97 units). A lane stops
  (issue 31, item 2) when (a) its step is below 2 float32 ulps of its scale (the Rust's test), (b) |f| is
  within its own rounding noise (``NOISE_ULPS`` = 0.75 ulps of the terms of f, the ``noise`` of each side
  below): near u → 1, where ln G(hi) − ln G(x) is at the float32 noise, the steps never got below 2 ulps
  and 8 % of the 16-lane packets ran all 12 iterations, or (c) after two steps d₁, d₂ the predicted error
  (C·d₂², C ≈ d₂/d₁² for Newton; K·d₂³, K ≈ d₂/d₁³ for Halley) is below the tolerance by a factor
  ``QUAD_SAFETY`` = 64 (this saves the confirming step). Iterations per 16-lane packet (max over its
  lanes; benches/beckmann_sampler_bench.py, 2^18 random θ and u): 2.00 above the horizon and 3.0 below,
  against 4.86 and 5.53 with Newton and (a) alone (the code before issue 31, item 2); Newton with (a)–(c)
  gave 3.00 and 4.01.
  Accuracy: the CDF error |CDF(x) − u| in units of the float32 floor (2^-24 + pdf(x)·ulp(x)) on a 331 θ ×
  103 u grid over θ ∈ (0, π), u ∈ [0, 1] (log-spaced into both tails; python_tests/test_jit_beckmann.py,
  ``test_slope_sampling_float32_floor``): at most 5.66 units (99.9th percentile 3.92), against 5.96 (3.71)
  with Newton and (a) alone and 5.95 for 40 iterations of it (the original criterion, on the grid first
  used: 7.0). With (b) at 1 ulp the maximum was 6.76, at 2 ulps 13.2; (c) at safety 1 gave 6.76, at 4–256
  the same 5.66. The slow lanes are u within ~1e-6 of 1 near the truncation, where the bracket bisects.
"""

import math

import drjit as dr
import mitsuba as mi

from .rng import ONE_MINUS_EPS
from .special import erfcx_deficit, erfcx_nonneg, exp_neg_sq, norm_inv

SQRT_PI = math.sqrt(math.pi)
INV_SQRT_PI = 1.0 / math.sqrt(math.pi)
FRAC_1_SQRT_2 = 1.0 / math.sqrt(2.0)

# The clamp of the uniform variates (beckmann.rs: 1e-12 .. 1 − 1e-12; 1 − 1e-12 is 1 in float32).
U_MIN = 1e-12

NEWTON_ITERATIONS = 12
# A lane's Newton iteration has converged when its step is below ~2 float32 ulps of its scale.
NEWTON_TOL = 2.0 ** -22
# Below the horizon Halley's step is taken only where −ln u ≥ HALLEY_MIN_L (see ``sample_slope_x``).
HALLEY_MIN_L = 0.1
EPS = 2.0 ** -24
# The rounding noise of the Newton function, in float32 ulps of its terms (see ``_newton_step``).
NOISE_ULPS = 0.75
# Safety factor of the quadratic-convergence stop (see ``_newton_step``).
QUAD_SAFETY = 64.0

def lambda_up(alpha_tan2):
    """Beckmann Λ ≥ 0 for an upward direction with (α tan θ)² = ``alpha_tan2`` (beckmann.rs):
    a = 1/(α tan θ), Λ = (e^{−a²}/(a√π) − erfc(a))/2 = e^{−a²}·d(a)/(2√π a) with d = ``erfcx_deficit``.
    0 for alpha_tan2 ≤ 0 and for a > 26, +∞ for +∞ (and NaN, as the Rust)."""
    r = mi.Float(alpha_tan2)
    rs = dr.select(r > 0.0, r, 1.0)
    s = dr.sqrt(rs)  # 1/a
    a2 = 1.0 / rs
    # Exact residual of the division: 1/r = a2·(1 + e) + O(e²).
    e = dr.fma(-a2, rs, 1.0)
    a2c = dr.minimum(a2, 1000.0)
    exp_term = dr.exp(-a2c) * (1.0 - a2c * e)
    a = dr.sqrt(a2c)
    v = exp_term * erfcx_deficit(a) * s * (0.5 * INV_SQRT_PI)
    v = dr.select(a2 > 676.0, 0.0, dr.maximum(v, 0.0))
    v = dr.select(dr.isfinite(r), v, dr.inf)
    return dr.select(r <= 0.0, 0.0, v)


def newton_monotone(fdf, x0, hi, scale, iterations=NEWTON_ITERATIONS, loop=False, cubic=False):
    """Solves f(x) = 0 for f increasing on (−∞, hi] with f(hi) ≥ 0 by Halley's (or Newton's) method from
    ``x0``, safeguarded by bisection once a bracket is known (beckmann.rs), per lane, in at most
    ``iterations`` steps. ``fdf(x)`` returns (f(x), f'(x), an estimate of the rounding error of f(x),
    f''(x)); f'' = 0 gives Newton's step. ``cubic``: the lanes whose f'' is given (their convergence is
    cubic, which the stop after two steps uses). A lane stops once its step is below
    NEWTON_TOL·(|x| + scale), once |f(x)| is below its rounding error, or once two steps predict a
    remaining error below the tolerance (``_newton_step``). Returns (x, converged).

    ``loop``: the steps run in a symbolic ``dr.while_loop`` that a packet leaves once all its lanes have
    stopped (most need 2–3 steps), else unrolled (while the inputs carry derivatives: a loop would need
    drjit's reverse-mode loop machinery). A stopped lane never moves again, so both give the same bits."""
    hi = mi.Float(hi)
    x0 = mi.Float(x0)
    lo = dr.full(mi.Float, -dr.inf, dr.width(hi))
    x = dr.select(dr.isfinite(x0) & (x0 < hi), x0, hi - 1.0)
    active = dr.full(mi.Bool, True, dr.width(x))
    prev = dr.full(mi.Float, dr.inf, dr.width(x))
    if loop:
        def body(i, x, lo, hi, prev, active):
            x, lo, hi, prev, active = _newton_step(fdf, x, lo, hi, prev, active, scale, cubic)
            return i + 1, x, lo, hi, prev, active

        _, x, lo, hi, prev, active = dr.while_loop((mi.UInt32(0), x, lo, hi, prev, active),
                                                   lambda i, x, lo, hi, prev, active: active & (i < iterations),
                                                   body, label="msx_beckmann_newton")
        return x, ~active
    for _ in range(iterations):
        x, lo, hi, prev, active = _newton_step(fdf, x, lo, hi, prev, active, scale, cubic)
    return x, ~active


def _newton_step(fdf, x, lo, hi, prev, active, scale, cubic):
    """One safeguarded Newton step of ``newton_monotone`` (lanes not ``active`` keep their x). ``prev`` is
    the length of the lane's previous step if that was a Newton step, else +∞."""
    fx, dfx, noise, d2fx = fdf(x)
    # Halley: x − f/(f'·(1 − f·f''/(2f'²))), the correction factor clamped into [1/2, 2].
    corr = dr.clip(1.0 - fx * d2fx / (2.0 * dfx * dfx), 0.5, 2.0)
    corr = dr.select(dr.isfinite(corr), corr, 1.0)
    nxt = x - fx / (dfx * corr)
    step = dr.abs(nxt - x)
    # Converged: the step is below float32 resolution (the Rust's |next − x| test, or f = 0), or f is
    # within its own float32 rounding noise of 0 (``noise``, an estimate of |f|'s rounding error): further
    # steps would only move x about inside the noise band (near u → 1, where they never get below 2 ulps).
    tiny = (dr.abs(nxt - x) <= NEWTON_TOL * (dr.abs(x) + scale)) & dr.isfinite(dfx)
    quiet = (dr.abs(fx) <= noise) & dr.isfinite(dfx)
    done = (fx == 0.0) | tiny | quiet
    upper = fx > 0.0
    hi = dr.select(active & upper, x, hi)
    lo = dr.select(active & ~upper, x, lo)
    inside = (nxt > lo) & (nxt < hi) & dr.isfinite(nxt)
    fallback = dr.select(dr.isfinite(lo), 0.5 * (lo + hi), x - (1.0 + dr.abs(x)))
    # Quadratic convergence (Newton): after two steps d₁ then d₂, the error left after d₂ is ≈ C·d₂² with
    # C ≈ d₂/d₁²; cubic (Halley, ``cubic`` lanes): ≈ K·d₂³ with K ≈ d₂/d₁³. The lane stops once
    # QUAD_SAFETY times that is below the tolerance (saves the confirming step whose only purpose is to
    # find the step tiny).
    tol = NEWTON_TOL * (dr.abs(x) + scale)
    s3 = QUAD_SAFETY * step * step * step
    quad = inside & dr.isfinite(dfx) & dr.isfinite(prev) & dr.select(cubic, s3 * step <= tol * prev * prev * prev,
                                                                     s3 <= tol * prev * prev)
    done |= quad
    nxt = dr.select(tiny & dr.isfinite(nxt), nxt, dr.select(inside, nxt, fallback))
    nxt = dr.select((fx == 0.0) | (quiet & ~tiny & ~inside), x, nxt)
    x = dr.select(active, nxt, x)
    prev = dr.select(active, dr.select(inside, step, dr.inf), prev)
    active &= ~done
    return x, lo, hi, prev, active


def sample_slope_x(cos_theta, sin_theta, u, iterations=NEWTON_ITERATIONS):
    """Samples the visible slope x (α = 1, direction at polar angle θ in the xz-plane): density
    ∝ (cos θ − x sin θ)·e^{−x²} on x < t = cot θ (beckmann.rs). Returns (x, valid); not valid straight
    down (sin θ < 1e-7, cos θ ≤ 0) or when x is not finite."""
    cos_theta = mi.Float(cos_theta)
    sin_theta = mi.Float(sin_theta)
    u = dr.clip(mi.Float(u), U_MIN, ONE_MINUS_EPS)
    vertical = sin_theta < 1e-7
    up = cos_theta >= 0.0
    sin_s = dr.select(vertical, 1.0, sin_theta)
    t = cos_theta / sin_s
    tau = dr.maximum(-t, 0.0)
    ln_u = dr.log(u)
    gauss = norm_inv(u) * FRAC_1_SQRT_2

    # Above the horizon, in x: G(x) = cos θ·erfc(−x)/2 + sin θ·e^{−x²}/(2√π) (all terms positive),
    # inverted in log space (see fdf below).
    hi_up = dr.minimum(t, 40.0)

    def ln_g(x):
        """(ln G(x), G'(x)/G(x)), without underflow for x ≤ 0: G = e^{−x²}·(cos θ·erfcx(−x) + sin θ/√π)/2."""
        ex = erfcx_nonneg(dr.abs(x))
        h = 0.5 * (cos_theta * ex + INV_SQRT_PI * sin_s)
        e2 = exp_neg_sq(x)
        g_pos = cos_theta * (1.0 - 0.5 * ex * e2) + (0.5 * INV_SQRT_PI) * sin_s * e2
        dens = (cos_theta - x * sin_s) * INV_SQRT_PI
        neg = x <= 0.0
        # One logarithm for both branches (the same bits as a log per branch, at half the cost).
        lg = dr.log(dr.select(neg, h, g_pos)) - dr.select(neg, x * x, 0.0)
        dlg = dr.select(neg, dens / h, dens * e2 / g_pos)
        # (ln G)'' = (ln G)'·(−1/(t − x) − 2x) − (ln G)'², with (ln G)'/(t − x) = sin θ/(√π·h)
        # (or sin θ·e2/(√π·g_pos) for x > 0): no division by t − x.
        q = dr.select(neg, sin_s / h, sin_s * e2 / g_pos) * INV_SQRT_PI
        d2lg = -q - 2.0 * x * dlg - dlg * dlg
        return lg, dlg, d2lg

    ln_g_hi = ln_g(hi_up)[0]
    c2 = cos_theta * cos_theta
    x_blend = c2 * gauss - (1.0 - c2) * dr.sqrt(-ln_u)
    # Where that guess lies beyond hi (u → 1 with the truncation at t active): near t the density is
    # ≈ sin θ·(t − x)·e^{−t²}/√π, so ln G(x) − ln G(t) ≈ −k(t − x)², k = sin θ·e^{−t²}/(2√π G(t)).
    k = sin_s * dr.exp(-hi_up * hi_up - ln_g_hi) * (0.5 * INV_SQRT_PI)
    x_trunc = hi_up - dr.sqrt(-ln_u / k)
    x0_up = dr.select(x_blend < hi_up, x_blend, x_trunc)

    # Below the horizon, in v = x − t = −s ≤ 0: ln G(x) − ln G(t) − ln u
    #   = −s(s + 2τ) + ln(b(x)/b(t)) − ln u, b(x) = d(z) + (1 − d(z))·s/z, z = −x = τ + s, τ = −t.
    b_t = erfcx_deficit(tau)

    def lg_and_dlg(v):
        s = dr.maximum(-v, 0.0)
        z = tau + s
        d = erfcx_deficit(z)
        b = d + (1.0 - d) * dr.select(z > 0.0, s / z, 0.0)
        b = dr.maximum(b, 1e-37)
        f = -s * (s + 2.0 * tau) + dr.log(b / b_t) - ln_u
        noise = (NOISE_ULPS * EPS) * (2.0 + s * (s + 2.0 * tau) + l)
        df = 2.0 * s / b
        return f, df, noise, -2.0 / b + df * 2.0 * (tau + s) - df * df

    # Initial guess (beckmann.rs): Gamma(2, 2τ) for steep directions, Rayleigh near the horizon; for
    # u → 1 both are replaced by the exact limit s² ≈ −b(t)·ln u (the Rust's Gamma guess is ∝ −ln u there).
    l = -ln_u
    s0 = dr.select(tau > 1.0, (l + dr.log(1.0 + l)) / (2.0 * dr.maximum(tau, 1.0)), dr.sqrt(l))
    s0 = dr.select(l < 0.1, dr.sqrt(l * b_t), s0)

    sqrt_l = dr.sqrt(l)
    halley_below = ~up & (l >= HALLEY_MIN_L)

    def above(x):
        # Above the horizon Newton runs on √(ln G(hi) − ln G(x)) − √(−ln u), the same root: that
        # function is nearly linear over the whole range (exactly so at θ = π/2, where G ∝ e^{−x²}; it
        # grows like |x| in the Gaussian tail and like t − x near the truncation at t), so Newton
        # converges in a few steps from any guess instead of crawling through a tail.
        la, da, d2a = ln_g(x)
        r = dr.maximum(ln_g_hi - la, 0.0)
        root_r = dr.sqrt(r)
        # Rounding noise of f: ln G(hi) and ln G(x) each carry ~NOISE_ULPS ulps of 1 + |ln G|.
        noise = (NOISE_ULPS * EPS) * ((2.0 + dr.abs(la) + dr.abs(ln_g_hi)) / (2.0 * root_r) + sqrt_l)
        d2f = (d2a + da * da / (2.0 * r)) / (2.0 * root_r)
        return sqrt_l - root_r, da / (2.0 * root_r), noise, d2f

    plain = not dr.grad_enabled(cos_theta, sin_theta, u)

    def fdf(x):
        if plain:  # each side only in the packets that have lanes there (a symbolic if_stmt branches)
            zero = (lambda x: tuple(dr.zeros(mi.Float, dr.width(x)) for _ in range(4)))
            fa, da, na, ea = dr.if_stmt((x,), up, above, zero, label="msx_beckmann_above")
            fb, db, nb, eb = dr.if_stmt((x,), ~up, lg_and_dlg, zero, label="msx_beckmann_below")
        else:
            (fa, da, na, ea), (fb, db, nb, eb) = above(x), lg_and_dlg(x)
        # f'' = 0 (a Newton step) below the horizon for u → 1 (−ln u < HALLEY_MIN_L), where Halley's
        # correction is ill-conditioned (f' → 0 at s → 0; it cost accuracy there, see the module docstring).
        d2f = dr.select(up, ea, dr.select(halley_below, eb, 0.0))
        return dr.select(up, fa, fb), dr.select(up, da, db), dr.select(up, na, nb), d2f

    x0 = dr.select(up, x0_up, -s0)
    hi = dr.select(up, hi_up, 0.0)
    scale = dr.select(up, 1.0, 1.0 / (1.0 + 2.0 * tau))
    root, _ = newton_monotone(fdf, x0, hi, scale, iterations, loop=plain, cubic=up | halley_below)
    x = dr.select(up, root, t + root)
    x = dr.select(vertical, gauss, x)
    valid = dr.select(vertical, cos_theta > 0.0, dr.isfinite(x))
    return x, valid


def sample_visible_std(w, u1, u2, iterations=NEWTON_ITERATIONS):
    """Visible normal (unnormalised) for the stretched (α = 1) unit direction ``w`` anywhere on the sphere
    (beckmann.rs): x slope by inverting the marginal CDF, y slope Gaussian with variance 1/2, rotated to
    w's azimuth. Returns (m, valid); ``valid`` is false where the Rust returns None (straight down,
    non-finite)."""
    w = mi.Vector3f(w)
    sin_theta = dr.sqrt(w.x * w.x + w.y * w.y)
    cos_theta = w.z
    has_azimuth = sin_theta > 0.0
    inv = 1.0 / dr.select(has_azimuth, sin_theta, 1.0)
    cos_phi = dr.select(has_azimuth, w.x * inv, 1.0)
    sin_phi = dr.select(has_azimuth, w.y * inv, 0.0)
    sx, valid = sample_slope_x(cos_theta, sin_theta, u1, iterations)
    # The y slope is independent: Gaussian with variance 1/2.
    sy = norm_inv(u2) * FRAC_1_SQRT_2
    # Rotate back to the azimuth of w.
    slope_x = cos_phi * sx - sin_phi * sy
    slope_y = sin_phi * sx + cos_phi * sy
    m = mi.Vector3f(-slope_x, -slope_y, 1.0)
    valid &= dr.isfinite(slope_x) & dr.isfinite(slope_y)
    return m, valid
