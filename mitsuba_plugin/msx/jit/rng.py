"""Each lane's random stream in the Dr.Jit engine: twin of ``src/rng.rs``.

As in the core (docs/conventions.md, "Random numbers"), a call's stream is a function of its own inputs
and the BSDF's ``seed``: the same inputs give the same numbers whatever the lane order, the number of
threads or the variant. The words are hashed into a 32-bit key (``mix32`` chained, as ``hash_words``
chains SplitMix64); the stream is counter-based: the k-th pair of numbers is TEA(key, k)
(``mi.sample_tea_32``, ``TEA_ROUNDS`` rounds), so the walk carries two 32-bit integers and needs no
generator state that depends on the lane's index. With Mitsuba's default of 4 rounds, consecutive
counters of one key are correlated (corr ≈ 0.09 between a word of pair 2 and of pair 3 over random keys,
≈ 100σ), which biased the walks measurably (a symmetric lobe's E[ω_o,x] at 6σ from 0); with 8 rounds a
residue remained measurable over 2²⁰ keys (corr ≈ 0.0025). The stream therefore runs 8 rounds and passes
each output word through ``mix32`` (a bijection with full avalanche): python_tests/test_jit_walks.py
checks the numbers' pairwise correlations and the symmetry of a sampled lobe. The numbers differ from the core's (PCG64 in float64): the engines agree
in distribution, which is what the engine-equality tests check.
"""

import drjit as dr
import mitsuba as mi

_GOLDEN = 0x9E3779B9


def mix32(x):
    """A bijective 32-bit mixer (xor-shift-multiply; the "lowbias32" constants)."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def bits(x):
    """The bit pattern of a float32 array as UInt32."""
    return dr.reinterpret_array(mi.UInt32, mi.Float(x))


def hash_words(seed, words):
    """Hashes the BSDF's seed (a Python int) and a sequence of per-lane float or UInt32 arrays."""
    h = mi.UInt32(mix32_int((seed & 0xFFFFFFFF) ^ mix32_int(seed >> 32)))
    for w in words:
        w = w if isinstance(w, mi.UInt32) else bits(w)
        h = mix32(h ^ (w + _GOLDEN))
    return h


def mix32_int(x):
    """``mix32`` on a Python int (for constants)."""
    x &= 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    return x ^ (x >> 16)


_TO_UNIT = 1.0 / 16777216.0  # 2^-24

# TEA rounds per pair of numbers (see the module docstring: 4 are not enough).
TEA_ROUNDS = 8


def _unit(u):
    """A UInt32 to a float in [0, 1) from its 24 high bits (exactly representable)."""
    return mi.Float(u >> 8) * _TO_UNIT


class Stream:
    """A counter-based stream: ``key`` (UInt32 per lane) and the counter of pairs drawn so far. The state
    a ``dr.while_loop`` must carry is ``(key, counter)`` (see :meth:`state` / :meth:`from_state`)."""

    def __init__(self, key, counter=None):
        self.key = key
        self.counter = mi.UInt32(0) if counter is None else counter

    def next2(self):
        a, b = mi.sample_tea_32(self.key, self.counter, TEA_ROUNDS)
        self.counter = self.counter + 1
        return _unit(mix32(a)), _unit(mix32(b))

    def next(self):
        return self.next2()[0]
