"""The float32 special functions of the Dr.Jit engine: twin of ``src/microfacet/special.rs``, with the
functions the core takes from libm in float64 and float32 cannot (``expm1``, ``log1p``, the ln Γ differences
of the correlated refraction factors, ``ln_l_beta`` of src/models/posfree/dielectric.rs).

Everything is traced float32 code in variant-agnostic types (mi.Float): branches are masks, nothing is read
back to Python. What differs from the Rust (float64) code:

* **erfc / erfcx.** The Rust calls libm. Here both come from one Chebyshev series of
  (1 + 2z)·erfcx(z) in y = (z − 2)/(z + 2), z ≥ 0 (the change of variable of Shepherd & Laframboise,
  "Chebyshev approximation of (1 + 2x)exp(x²)erfc x in 0 ≤ x < ∞", Math. Comp. 36, 1981; the
  coefficients below are my own fit, computed with mpmath at 50 digits by Chebyshev interpolation on 80
  nodes and truncated where the dropped coefficients sum to < 5e-10). Relative accuracy of ``erfcx`` on
  [0, ∞): a few float32 ulps (the series' own error is < 5e-10).
* **The deficit d(z) = 1 − √π·z·erfcx(z)** (``erfcx_deficit``), which the Rust never names: Λ and the
  sampler below the horizon are differences of nearly equal terms (d ≈ 1/(2z²) for large z). Computing
  them from erfcx would lose 2z² in relative precision, harmless in float64 but not in float32, so d has
  its own Chebyshev series of (1 + 2z²)·d(z) in the same variable (same fit, 17 terms).
  Λ = e^{−a²}·d(a)/(2√π a) with a = 1/(α tan θ); e^{−a²} is evaluated with the rounding error of
  a² = 1/alpha_tan2 compensated by an FMA residual, so Λ is accurate relative to the float32 input.
  Measured relative errors against float64 (python_tests/test_jit_beckmann.py): erfcx ≤ 4.5 ulps on
  [−9, 1e8], erfc ≤ 5.3 ulps (where ≥ FLT_MIN), d ≤ 6.0 ulps, Λ ≤ 9.3 ulps (5.6e-7) on alpha_tan2 ∈
  [1e-6, 1e6] (the few values below FLT_MIN, near a = 9.3, are subnormal or flushed to 0).
* **norm_inv** is √2·erfinv(2p − 1) through ``dr.erfinv`` (the Rust: Acklam + Halley). In float32,
  2p − 1 rounds to ±1 for p < 2^-25, so p is clamped to keep 2p − 1 in [−(1 − 2^-24), 1 − 2^-24]: the
  Gaussian tails beyond |x| ≈ 5.4 (mass < 1e-7, below the 2^-24 resolution of a float32 sample anyway)
  are not produced.
* **expm1 / log1p** (not in drjit) are Kahan's corrections, so that a hit probability 1 − e^{Λt} of a
  near-vertical ray and the Beta factors keep their relative precision. They come in two roundings of the
  same formula, the product first (``expm1``, ``log1p``: the height walks) or the ratio first
  (``expm1_ratio``, ``log1p_ratio``: ``ln_l_beta`` and the position-free glass walks); the two differ in
  the last ulp, and a walk moved from one to the other draws other paths where a rounding flips a decision
  (docs/testing.md, "Heavy-tailed estimators and fixed seeds"), so each caller keeps the one it was
  measured with.
* **ln_l_beta**: the core takes L·B(L, 1+Λ) from three ln Γ in float64; in float32 they cancel (for Λ → 0
  the result is O(Λ) against terms O(L ln L)), so it is written as a sum of terms that are each
  O(min(L, Λ)) (shifted Stirling differences and log1p sums), and for L + Λ ≤ ½ as the Taylor series of
  ln Γ(1 + x) with the LΛ factored out: relative error below 1e-6 everywhere
  (python_tests/test_jit_dielectric.py checks it against mpmath).
"""

import math

import drjit as dr
import mitsuba as mi

from .rng import ONE_MINUS_EPS

# ------------------------------------------------------------------ the error functions (special.rs)

# Chebyshev coefficients (see the module docstring), variable y = (z − K)/(z + K) = 1 − 2K/(z + K).
_CHEB_K = 2.0
# (1 + 2z)·erfcx(z); the limit at z = ∞ is 2/√π.
_ERFCX_COEFFS = (
    1.1760066556, 0.02577967387, -0.10659315068, 0.038808879574, -0.0054148999309,
    -0.00040815257282, 0.00019843768249, 9.8425327761e-06, -7.7632655612e-06, -7.1740014531e-07,
    3.1406949527e-07, 6.1884236979e-08, -9.8906199883e-09, -4.5953998273e-09,
)
# (1 + 2z²)·(1 − √π z erfcx(z)); the limit at z = ∞ is 1.
_DEFICIT_COEFFS = (
    0.88738519632, 0.10143653511, 0.074967864417, -0.096353072257, 0.038487246152,
    -0.0053770828936, -0.00087191411862, 0.00030838528483, 3.389469614e-05, -1.5449778952e-05,
    -2.4843462098e-06, 7.0486497299e-07, 2.1209079124e-07, -1.944399084e-08, -1.6102562592e-08,
    -1.109572989e-09, 9.1461842266e-10,
)


def _chebyshev(coeffs, z):
    """Σ c_k T_k(y), y = 1 − 2K/(z + K), by Clenshaw's recurrence (z ≥ 0; z = +∞ gives y = 1)."""
    y = 1.0 - (2.0 * _CHEB_K) / (z + _CHEB_K)
    y2 = 2.0 * y
    b1 = mi.Float(0.0)
    b2 = mi.Float(0.0)
    for c in reversed(coeffs[1:]):
        b1, b2 = dr.fma(y2, b1, c - b2), b1
    return dr.fma(y, b1, coeffs[0] - b2)


def exp_neg_sq(x):
    """e^{−x²} with the rounding error of x² compensated (an FMA gives x² = h + l exactly)."""
    x = mi.Float(x)
    h = x * x
    l = dr.fma(x, x, -h)
    l = dr.select(dr.isfinite(h), l, 0.0)
    return dr.exp(-h) * (1.0 - l)


def erfcx(x):
    """Scaled complementary error function e^{x²}·erfc(x) (special.rs). Relative accuracy ~1e-7 on
    x ≥ 0 (including x → ∞, where it is 1/(x√π)); for x < 0 it is 2e^{x²} − erfcx(−x) (+∞ below ≈ −9.4)."""
    x = mi.Float(x)
    z = dr.abs(x)
    pos = _chebyshev(_ERFCX_COEFFS, z) / (1.0 + 2.0 * z)
    return dr.select(x >= 0.0, pos, 2.0 / exp_neg_sq(x) - pos)


def erfcx_nonneg(z):
    """``erfcx`` for z ≥ 0 only (the same bits there), without tracing the x < 0 branch's exp and division
    (the Beckmann sampler's Newton step, msx/jit/beckmann.py, needs erfcx(|x|) only)."""
    z = mi.Float(z)
    return _chebyshev(_ERFCX_COEFFS, z) / (1.0 + 2.0 * z)


def erfc(x):
    """Complementary error function with float32 relative accuracy for large positive x (special.rs)."""
    x = mi.Float(x)
    tail = erfcx(dr.abs(x)) * exp_neg_sq(x)
    return dr.select(x >= 0.0, tail, 2.0 - tail)


def erfcx_deficit(z):
    """d(z) = 1 − √π·z·erfcx(z) for z ≥ 0, relatively accurate (d ≈ 1/(2z²) for large z); 0 at z = ∞."""
    z = mi.Float(z)
    return _chebyshev(_DEFICIT_COEFFS, z) / (1.0 + 2.0 * z * z)


def norm_inv(p):
    """Inverse of the standard normal CDF, √2·erfinv(2p − 1), with 2p − 1 clamped into
    [−(1 − 2^-24), 1 − 2^-24] so that it stays finite (|x| ≤ 5.42) for every p ∈ [0, 1]."""
    q = dr.clip(2.0 * mi.Float(p) - 1.0, -ONE_MINUS_EPS, ONE_MINUS_EPS)
    return math.sqrt(2.0) * dr.erfinv(q)


# ------------------------------------------------------------------ expm1, log1p, optical depth


def expm1(x):
    """e^x − 1 for x ≤ 0 without cancellation near 0 (Kahan: (u − 1)·x / ln u with u = e^x)."""
    u = dr.exp(x)
    um1 = u - 1.0
    v = um1 * x / dr.log(u)
    return dr.select(u == 1.0, x, dr.select(um1 == -1.0, -1.0, v))


def log1p(x):
    """ln(1 + x) for x > −1 without cancellation near 0 (Kahan: ln u · x / (u − 1) with u = 1 + x)."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * x / (u - 1.0))


def optical_depth(u):
    """E = −ln(1 − U), an Exp(1) depth (finite: U is clamped below 1)."""
    u = dr.clip(u, 0.0, ONE_MINUS_EPS)
    return -dr.log(1.0 - u)


def log1p_ratio(x):
    """``log1p`` with the ratio first, ln u · (x/(u − 1)): the rounding ``ln_l_beta`` is written with."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * (x / (u - 1.0)))


def expm1_ratio(x):
    """``expm1`` with the ratio first, (u − 1)·(x/ln u): the rounding of the position-free glass walks'
    continue factor (``posfree_dielectric.continue_up``)."""
    u = dr.exp(x)
    um1 = u - 1.0
    return dr.select(u == 1.0, x, dr.select(um1 == -1.0, -1.0, um1 * (x / dr.log(u))))


# ------------------------------------------------------------------ ln Γ differences (posfree/dielectric.rs)

# Shift of the arguments before Stirling's series in ``ln_l_beta``, and the series' coefficients
# B_2k/(2k(2k−1)) of 1/z^(2k−1), k = 1..5: truncated after 1/z⁹, its error is below 691/(360360 z¹¹) < 5e-10
# for z ≥ 4.
_STIRLING_SHIFT = 3
_STIRLING = (1.0 / 12.0, -1.0 / 360.0, 1.0 / 1260.0, -1.0 / 1680.0, 1.0 / 1188.0)


def _stirling_tail_diff(x, b):
    """s(x + b) − s(x) of ln Γ(z) = (z − ½) ln z − z + ½ ln 2π + s(z), s(z) = Σ_k c_k/z^(2k−1) (x ≥ 4), as
    b times a sum of positive terms (no cancellation as b → 0): with r = 1/x, t = 1/(x + b),
    t^m − r^m = (t − r)·S_m, S_m = Σ_{i<m} t^i r^(m−1−i) (S_1 = 1, S_{m+1} = t·S_m + r^m), t − r = −b·r·t."""
    r = 1.0 / x
    t = 1.0 / (x + b)
    acc = _STIRLING[0] * 1.0
    s_m, r_m = mi.Float(1.0), r  # S_1, r^1
    for k in range(1, len(_STIRLING)):
        for _ in range(2):  # S_m → S_{m+2}
            s_m = t * s_m + r_m
            r_m = r_m * r
        acc = acc + _STIRLING[k] * s_m
    return -b * r * t * acc


# ζ(k), k = 2, 3, …: the Taylor coefficients of ln Γ(1 + x) = −γx + Σ_{k≥2} (−1)^k ζ(k) x^k / k.
_ZETA = (1.6449340668482264, 1.2020569031595942, 1.0823232337111381, 1.03692775514337, 1.0173430619844492,
         1.008349277381923, 1.0040773561979444, 1.0020083928260821, 1.000994575127818, 1.0004941886041194,
         1.000246086553308, 1.0001227133475785, 1.0000612481350588, 1.000030588236307, 1.0000152822594086,
         1.0000076371976379, 1.000003817293265, 1.0000019082127165, 1.0000009539620338, 1.0000004769329869,
         1.0000002384505027, 1.000000119219926, 1.000000059608189)
# a + b below which ``ln_l_beta`` takes the series (its truncation after the last ζ is < s^22 ≈ 2e-7 of the
# value at s = 1/2).
_SERIES_MAX = 0.5


def _ln_l_beta_series(a, b):
    """ln Γ(a+1) + ln Γ(b+1) − ln Γ(a+b+1) for a + b ≤ ½ from the Taylor series of ln Γ(1 + x): the −γ
    terms cancel exactly and the rest is −ab·Σ_{k≥2} (−1)^k ζ(k)/k·q_k with q_k = (s^k − a^k − b^k)/(ab),
    s = a + b, by the recurrences e_k = a^k + b^k = s·e_{k−1} − p·e_{k−2} and q_k = s·q_{k−1} + e_{k−2}
    (p = ab; every q_k a sum of positive terms)."""
    s, p = a + b, a * b
    e_prev, e = mi.Float(2.0), s  # e_0, e_1
    q = mi.Float(0.0)  # q_1
    total = mi.Float(0.0)
    for i, z in enumerate(_ZETA):
        k = i + 2
        q = s * q + e_prev  # q_k (uses e_{k−2})
        e_prev, e = e, s * e - p * e_prev  # e_{k−1}, e_k
        term = (z / k) * q
        total += term if k % 2 == 0 else -term
    return -p * total


def _ln_l_beta_stirling(a, b):
    """The shifted Stirling form of ``ln_l_beta`` for a = max(L, Λ), b = min(L, Λ) (its docstring)."""
    n = float(_STIRLING_SHIFT)
    x0, x1 = n + 1.0, a + n + 1.0
    v = ((n + 0.5) * log1p_ratio(b / x0) - (a + n + 0.5) * log1p_ratio(b / x1) - b * log1p_ratio(a / (x0 + b))
         + _stirling_tail_diff(x0, b) - _stirling_tail_diff(x1, b))
    for k in range(1, _STIRLING_SHIFT + 1):
        # log1p(b/(a+k)) − log1p(b/k) = log1p(−ab/((a+k)(k+b))), the argument in (−1, 0].
        v += log1p_ratio(-(a / (a + k)) * (b / (b + k)))
    return v


def ln_l_beta(l, lam, branch=False):
    """ln(L·B(L, 1+Λ)) = ln Γ(L+1) + ln Γ(Λ+1) − ln Γ(L+Λ+1) (≤ 0 for L, Λ ≥ 0); 0 when L or Λ is 0,
    −∞ when one is infinite (``ln_l_beta`` of src/models/posfree/dielectric.rs).

    The value is symmetric in (L, Λ); let b = min, a = max. For a + b ≤ ½, ``_ln_l_beta_series`` (the
    value is −(π²/6)·ab + …, second order). Otherwise, with n = ``_STIRLING_SHIFT``, shifting every
    argument by n (Γ(x+1) = Γ(x+1+n)/∏_{k=1..n}(x+k)) and writing the differences of ln Γ of Stirling's
    series as D(x, b) = ln Γ(x+b) − ln Γ(x) = (x − ½) log1p(b/x) + b ln(x+b) − b + s(x+b) − s(x) gives

        D(n+1, b) − D(a+n+1, b) + Σ_{k=1..n} log1p(−ab/((a+k)(k+b)))

    (the sum is Σ [log1p(b/(a+k)) − log1p(b/k)]), whose terms are each O(b) (the −b and the b ln terms
    combine into −b·log1p(a/(n+1+b))): float32 keeps its relative precision as b → 0, where the core's
    three ln Γ would cancel.

    ``branch``: each form is computed only in the packets that have lanes of it (same bits; ignored while
    the inputs carry derivatives). A walk's first vertex has L ≥ 1, so its packets skip the series."""
    l, lam = mi.Float(l), mi.Float(lam)
    a, b = dr.maximum(l, lam), dr.minimum(l, lam)
    series = a + b <= _SERIES_MAX
    if branch and not dr.grad_enabled(l, lam):
        # Each form only in the packets that have lanes of it (a symbolic if_stmt branches per packet; the
        # lanes of the other form are overwritten by the select below, so the bits are the same).
        zero = lambda a, b: dr.zeros(mi.Float, dr.width(a))  # noqa: E731
        v = dr.if_stmt((a, b), ~series, _ln_l_beta_stirling, zero, label="msx_ln_l_beta_stirling")
        v = dr.select(series, dr.if_stmt((a, b), series, _ln_l_beta_series, zero, label="msx_ln_l_beta_series"), v)
    else:
        v = _ln_l_beta_stirling(a, b)
        v = dr.select(series, _ln_l_beta_series(a, b), v)
    v = dr.minimum(v, 0.0)
    v = dr.select(dr.isfinite(l) & dr.isfinite(lam), v, -dr.inf)
    return dr.select((lam == 0.0) | (l == 0.0), 0.0, v)


def l_beta(l, lam, branch=False):
    """L·B(L, 1+Λ) = Γ(L+1)Γ(Λ+1)/Γ(L+Λ+1) ∈ [0, 1] (``l_beta`` of src/models/posfree/dielectric.rs)."""
    return dr.exp(ln_l_beta(l, lam, branch))


def beta(a, b):
    """The Beta function B(a, b) for a, b > 0 (``beta`` of src/models/posfree/dielectric.rs, which the PT does not use): B(a, b) =
    exp(ln_l_beta(a, b − 1))/a for b ≥ 1, and B(a, b) = B(a, b + 1)·(a + b)/b below."""
    a, b = mi.Float(a), mi.Float(b)
    small = b < 1.0
    bb = dr.select(small, b + 1.0, b)
    v = dr.exp(ln_l_beta(a, bb - 1.0)) / a
    return dr.select(small, v * (a + b) / b, v)
