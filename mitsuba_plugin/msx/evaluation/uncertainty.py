"""Uncertainty of the numbers that rank models, and the ranking rule.

Pure NumPy (no Mitsuba): the report and the tests share it.

bias² of a row is the relative MSE of its seed mean against the reference with both noises removed,
``mean((m − R)²) − var(m) − noise(R)`` over the object's pixels and channels, divided by ``mean(R²)``
(renders.statistics). Its standard error comes from the same renders: every pixel is an independent Monte
Carlo estimate (its own random stream, its variance measured from the independent seeds), so the
per-pixel contributions ``q_p`` to that mean are independent and ``se = std(q_p) / √P``. This is
conservative: the spread of ``q_p`` also counts how the bias itself varies over the object (it is exact
when the bias is zero, test_ranking.py). Two rows are compared on the same pixels, so the standard error of
their difference is that of ``q_p^A − q_p^B`` (a paired comparison: what the two rows share — the
reference's noise, the variation of the bias over the object — cancels).

Ranking rule (stated on the page): sorted by bias², a row joins the group of the best row not yet placed
unless its bias² exceeds that row's by more than ``Z`` standard errors of the difference; rows of one group
are "tied within noise".
"""

from __future__ import annotations

import math

import numpy as np

Z = 3.0  # a difference counts when it exceeds Z standard errors (two-sided false alarm ≈ 0.27 % per pair)
# ... and float32 rounding: renders are float32, so two rows that are the same computation (single and the
# built-in, same seeds) differ by rounding only; their paired standard error is then ~0 and rounding alone
# would read as "significant". Differences below this relative size are ties.
ROUNDING = 1e-5


def bias2_terms(images, reference, mask, ref_noise=0.0):
    """Per object pixel p: q_p with mean(q) = the row's bias² (relative, like rel_mse). images: the seeds
    (≥ 2) of one row at one spp; the seed variance of each pixel is removed from its squared error."""
    n = len(images)
    if n < 2:
        raise ValueError("bias² needs at least two independent seeds")
    m = sum(images) / n
    r = reference[mask]
    den = float(np.mean(r * r))
    d2 = ((m - reference)[mask] ** 2).sum(axis=1)                                  # [P], summed over channels
    var = (sum(((i - m)[mask]) ** 2 for i in images) / (n - 1)).sum(axis=1) / n     # variance of the mean
    channels = r.shape[1] if r.ndim == 2 else 1
    return (d2 - var) / (channels * den) - ref_noise


def mean_terms(images, reference, mask):
    """Per object pixel: u_p with mean(u) = the signed relative error of the mean radiance over the object,
    (mean(m) − mean(R)) / mean(R) (all channels)."""
    m = sum(images) / len(images)
    den = float(np.mean(reference[mask]))
    return ((m - reference)[mask]).mean(axis=1) / den if den > 0 else np.full(int(mask.sum()), np.nan)


def mean_se(terms):
    """(mean, standard error) of per-pixel terms."""
    t = np.asarray(terms, dtype=np.float64)
    if t.size < 2:
        return float(t.mean()) if t.size else float("nan"), float("nan")
    return float(t.mean()), float(t.std(ddof=1) / math.sqrt(t.size))


def diff_se(a, b):
    """Standard error of bias²(a) − bias²(b). a, b: dicts with 'se' and optionally 'terms' (per-pixel
    contributions on the same pixels: then the paired standard error)."""
    ta, tb = a.get("terms"), b.get("terms")
    if ta is not None and tb is not None and len(ta) == len(tb) and len(ta) > 1:
        return float(np.std(np.asarray(ta) - np.asarray(tb), ddof=1) / math.sqrt(len(ta)))
    return math.hypot(a["se"], b["se"])


def _floor(a, b):
    return ROUNDING * max(abs(a["bias2"]), abs(b["bias2"]))


def significantly_lower(a, b, z=Z):
    """True if a's bias² is lower than b's by more than z standard errors of the difference (and more than
    float32 rounding)."""
    return b["bias2"] - a["bias2"] > z * diff_se(a, b) + _floor(a, b)


def differ(a, b, z=Z):
    """True if the bias² of a and b differ beyond noise (either way)."""
    return significantly_lower(a, b, z) or significantly_lower(b, a, z)


def rank(entries, z=Z):
    """Groups of tied entries, best first. entries: dicts with 'label', 'bias2', 'se' (and optionally
    'terms'). Sorted by bias²; each group is led by the best entry not yet placed and holds every later entry
    whose bias² does not exceed the leader's by more than z standard errors of the difference."""
    left = sorted(entries, key=lambda e: e["bias2"])
    groups = []
    while left:
        lead = left[0]
        tied = [e for e in left if not significantly_lower(lead, e, z)]
        groups.append(tied)
        left = [e for e in left if e not in tied]
    return groups


def ranking_text(groups):
    """'a < b = c < d' style summary: '=' joins rows tied within noise."""
    return " < ".join(" = ".join(e["label"] for e in g) for g in groups)


def sign_word(value, se, z=Z, words=("too dark", "too bright")):
    """'too dark' / 'too bright' when the signed error is beyond z standard errors, else 'within noise'."""
    if not (math.isfinite(value) and math.isfinite(se)):
        return "—"
    if abs(value) <= z * se:
        return "within noise"
    return words[0] if value < 0 else words[1]


def spp_to_reach(target, bias2, k):
    """spp for rel MSE = target under rel_mse(n) = bias² + k/n, k = variance × spp of one render (inf below
    the bias floor, nan without a variance)."""
    if not (math.isfinite(k) and k > 0):
        return float("nan")
    room = target - max(bias2, 0.0)
    return k / room if room > 0 else float("inf")


# What a time to a target is (the page and times.csv say it for every row and target).
MEASURED, EXTRAPOLATED, NOT_REACHABLE, UNDECIDED = "measured", "extrapolated", "not reachable", "undecided"


def target_status(rms_pct, bias2, bias2_se, k, top_spp, z=Z):
    """Where a row stands against a target relative RMS error (in %), from its fit rel_mse(n) = bias² + k/n:
    status MEASURED when the target's spp lies inside the row's sweep (at or below its largest spp, whose
    error is then at or below the target), EXTRAPOLATED with factor = the spp needed ÷ the largest spp,
    NOT_REACHABLE when the bias floor exceeds the target by more than z standard errors (the floor itself is
    measured: floor_pct ± floor_se_pct), UNDECIDED when the fit puts the floor above the target but within
    noise. spp: the spp the fit needs (inf below the floor)."""
    target = (rms_pct / 100.0) ** 2
    floor = 100.0 * math.sqrt(max(bias2, 0.0))
    floor_se = 100.0 * bias2_se / (2.0 * math.sqrt(bias2)) if bias2 > 0 else float("nan")
    out = dict(target=rms_pct, spp=spp_to_reach(target, bias2, k), factor=float("nan"), floor_pct=floor,
               floor_se_pct=floor_se)
    if bias2 - z * bias2_se > target:
        return dict(out, status=NOT_REACHABLE)
    n = out["spp"]
    if math.isnan(n):
        return dict(out, status=UNDECIDED)
    if n == float("inf"):
        return dict(out, status=UNDECIDED)
    if n <= top_spp:
        return dict(out, status=MEASURED, factor=1.0)
    return dict(out, status=EXTRAPOLATED, factor=n / top_spp)


def wants_more(statuses, top_spp, cap_spp):
    """The adaptive sweep's rule (renders.sweep): double the row's spp when a target it has not measured is
    predicted within the cap (its spp ≤ cap_spp) and the doubling stays within the cap. Targets the bias floor
    makes unreachable, and targets predicted beyond the cap, stop it."""
    if 2 * top_spp > cap_spp:
        return False
    return any(s["status"] == EXTRAPOLATED and s["spp"] <= cap_spp for s in statuses)


def time_in_range(t, seconds):
    """(t, extrapolation factor): factor 1 when t lies inside the measured span of render times (or below
    its top: the sweep measured longer renders), else t / the longest measured render."""
    if t is None or not math.isfinite(t):
        return t, float("nan")
    top = max(seconds)
    return t, (1.0 if t <= top else t / top)
