"""What every random walk of the Dr.Jit engine shares: twin of ``src/walk/mod.rs``."""

import drjit as dr

from .microfacet import max_channel


def russian_roulette_keep(throughput, u, keep):
    """Russian roulette that keeps a path surely while its largest channel is ≥ ``keep`` (a Float per
    lane) and otherwise survives with probability max/keep, dividing the throughput by it (unbiased).
    ``u`` is the lane's uniform number. Returns (throughput, survived)."""
    q = dr.minimum(max_channel(throughput) / keep, 1.0)
    survived = (q > 0.0) & ((q >= 1.0) | (u < q))
    return dr.select(survived, throughput / q, 0.0), survived
