"""The exit probabilities of monotone paths in per-lane registers (Cui et al. 2023 with Bitterli & d'Eon
2022's exit probability), the Dr.Jit engine's twin of ``src/models/invariance/recursion.rs``
(``MonotoneExit``): a conductor path is a run of a ≥ 1 downward directions d_0..d_{a−1} followed by upward
ones, and the probability that it hits at every vertex and leaves along an upward x is a column recursion
over the downward run (``recursion.rs``, "Monotone paths"). Its state is the |Λ| of the downward directions
and one value g_i per downward direction: a per-path array whose length is the length of the downward run.

Registers, not arrays. A local array (``dr.alloc_local``) cannot be compiled inside a symbolic call by
drjit 1.5's LLVM backend, and Mitsuba calls every BSDF through one; so the run lives in K per-lane
registers, Python lists of mi.Float carried through the walk's ``dr.while_loop`` (``MonotoneExit``:
K = ``CONDUCTOR_RUN_SLOTS`` = 20 slots of |Λ| and of g; the dielectric's ``PieceChain``, jit/invariance_
dielectric.py: K = ``DIELECTRIC_RUN_SLOTS`` = 18 slots of L_i and π), plus the run length a. An indexed
write is a select over the K slots, the O(a) passes over the run are unrolled over the K slots and masked by
i < a; the slots from ``RUN_SLOTS_ALWAYS`` = 4 on sit in a ``dr.if_stmt`` that a packet of lanes whose runs
are all shorter skips (``over_run``; the same bits as without it, a test). Up to K the state is the core's,
exactly; a path whose downward run would be longer than K (or than the bounce cap, when that is smaller)
**ends there**: the push of its (K+1)-th downward direction fails, the walk stops, and what it would still
have added (its higher orders, or a sampled direction: the sample is invalid) is lost — a bias of at most
the fractions below. The BDPT's connections use the same class with one slot per direction of their path.

K is measured, not guessed: the run length a (conductor) / piece count (dielectric) at the end of each
lane of walks with room for 64 (default max_bounces 64), eval (ω_o uniform on the hemisphere / sphere) and
sample, Cu / η = 1.5168, GGX and Beckmann, α ∈ {1, 2, 4}, θ_i ∈ {0, 0.4, 0.8, 1.3, 1.5, 1.55} (dielectric:
from both sides). Grazing incidence gives *short* runs (P(a > 4) ≤ 2e-6 at θ_i = 1.55); the longest come at
normal incidence with α = 4, GGX (Beckmann's are shorter). The tail is faster than geometric (each further
step ×0.2–0.3 at a ≈ 15–20). Worst cases, fraction of lanes with a > K (paths) and of the estimate's sum
they carry (energy; their whole estimates, a bound on what the walk ending at K loses), eval / sample:

- conductor, GGX α = 4, θ_i = 0 (8.4e7 lanes): K = 17: 5.0e-6 / 5.7e-6 paths, 2.3e-6 / 2.5e-6 energy;
  K = 18: 1.0e-6 / 1.5e-6, 5.6e-7 / 6.2e-7; K = 19: 3.3e-7 / 3.3e-7, 1.0e-7 / 1.3e-7; **K = 20**: 4.8e-8 /
  6.0e-8 (4 / 5 lanes), 3.7e-9 / 2.3e-8; K = 21: 1.2e-8 / 2.4e-8; no run longer than 22. Other cases are
  shorter: α = 4, θ_i = 0.4: a > 18 in 3e-8; α = 2, θ_i = 0: a > 13 in 6e-8; α = 4, θ_i = 0.8: a > 16 in
  6e-8 (3.4e7 lanes each).
- dielectric from below (total internal reflection lengthens the run), GGX α = 4, θ_i = 0 (5.5e7 lanes):
  K = 15: 1.6e-6 / 2.2e-6 paths, 7.1e-6 / 2.1e-6 energy; K = 16: 5.1e-7 / 4.6e-7, 1.2e-6 / 3.7e-7; K = 17:
  3.7e-8 / 1.1e-7, 1.6e-7 / 5.9e-8; **K = 18**: 0 / 1.8e-8 (0 / 1 lane), 0 / 9.8e-9; no run longer than
  20. θ_i = 0.4 from below: a > 15 in 2.4e-7 / 3.6e-7 of 1.7e7 lanes, none above 17; from above: a > 8 in
  ≤ 1.2e-7.

A larger α than 4 (outside the measured range) gives longer runs, so more paths end at K.
"""

import drjit as dr
import mitsuba as mi

# Registers of a downward run (conductor ``MonotoneExit``, dielectric ``PieceChain``), chosen by
# measurement (the module docstring): a path whose run would be longer ends there.
CONDUCTOR_RUN_SLOTS = 20
DIELECTRIC_RUN_SLOTS = 18
# Slots every pass visits; the others only under ``dr.if_stmt(a > RUN_SLOTS_ALWAYS)``, which the LLVM backend
# compiles to a branch that a packet of lanes skips when none of them has a run that long (most runs are
# 1–3 directions: the passes over all the slots cost 30 % of the invariance walk's render time, measured).
RUN_SLOTS_ALWAYS = 4

def over_run(n, a, step, carry, reverse=True, unrolled=False):
    """``carry = step(i, carry)`` for the slots i of a run held in ``n`` registers, n−1 … 0 (``reverse``) or
    0 … n−1; the slots from ``RUN_SLOTS_ALWAYS`` on inside ``dr.if_stmt(a > RUN_SLOTS_ALWAYS)``, a branch that
    lanes with shorter runs skip. ``step`` must leave the carry unchanged for the slots i ≥ ``a`` (``a``: the
    slots in use, a UInt32 per lane).

    ``unrolled``: every slot without the branch (the same bits), for a walk whose derivative is propagated
    in forward mode through its loop: drjit 1.5's forward mode cannot take the branch. Outside a symbolic
    scope it fails ("jit_var_schedule: not permitted", it tries to evaluate a symbolic variable); inside
    Mitsuba's symbolic calls it runs but drops the tangent of every value the steps read from their closure
    (measured: ∂f/∂α −0.0912 for −0.0946 on a lane of the conductor walk), and with those values handed to
    the branch as arguments the LLVM backend aborts the process ("Instruction does not dominate all uses").
    A walk traced with ``mf_sample`` whose inputs carry no derivative — every call of ``prb``'s primal passes,
    which suspend gradients, and the adjoint pass's ``sample`` — keeps the branch: no derivative goes through
    it (``MonotoneExit.new``'s callers decide; ``walk.carries_gradients``). The run's owner (``MonotoneExit``,
    ``PieceChain``) carries the flag."""
    lo = min(RUN_SLOTS_ALWAYS, n)
    head, tail_slots = list(range(lo)), list(range(lo, n))
    if reverse:
        head.reverse()
        tail_slots.reverse()

    def tail(*c):
        for i in tail_slots:
            c = step(i, c)
        return c

    if not reverse:
        for i in head:
            carry = step(i, carry)
    if tail_slots and unrolled:
        carry = tail(*carry)
    elif tail_slots:
        carry = dr.if_stmt(args=tuple(carry), cond=a > lo, true_fn=tail, false_fn=lambda *c: c, label="msx_run_tail")
    if reverse:
        for i in head:
            carry = step(i, carry)
    return carry


def push_down(run, a, has_up, l, active, unrolled):
    """Appends ``l`` to a downward run held in the registers ``run`` (a list; slots 0..a−1 in use) where
    ``active``, unless an upward direction came before (``has_up``: the path would not be monotone) or the
    run is full: the shared step of ``MonotoneExit`` and ``PieceChain`` (jit/invariance_dielectric.py).
    Returns (run, a, pushed)."""
    ok = active & ~has_up & (a < len(run))

    def step(i, slots):
        if i == 0:
            return slots
        return slots[:i] + (dr.select(ok & (a == i), l, slots[i]),) + slots[i + 1:]

    run = list(over_run(len(run), a + 1, step, tuple(run), unrolled=unrolled))
    return run, dr.select(ok, a + 1, a), ok


class MonotoneExit:
    """Incremental exit probabilities of a monotone path d_0..d_m (twin of ``MonotoneExit``), per lane in
    ``n`` registers, unrolled at trace time: Python lists ``down`` (|Λ| of the downward run; slot i < a holds
    its i-th direction) and ``g`` (the column's second term, normalised by the hit probability as the
    Rust's), the run length ``a`` (UInt32), ``has_up`` (an upward direction was pushed) and the hit
    probability ``hit`` = H_m. Every indexed access is a select over the slots, every pass over the run
    is masked by i < a. Pass :meth:`state` through the walk's loop and rebuild with :meth:`from_state`."""

    def __init__(self, down, g, a, has_up, hit, unrolled=False):
        self.down, self.g = list(down), list(g)
        self.a, self.has_up, self.hit = a, has_up, hit
        self.n = len(self.down)
        # How its passes are traced (``over_run``): a Python bool of the trace, not loop state.
        self.unrolled = unrolled

    @staticmethod
    def new(l0, n, unrolled=False):
        """A path starting with d_0 (downward) of |Λ(d_0)| = ``l0``, room for ``n`` downward directions."""
        return MonotoneExit([mi.Float(l0)] + [mi.Float(1.0) for _ in range(n - 1)], [mi.Float(0.0) for _ in range(n)],
                            mi.UInt32(1), mi.Bool(False), mi.Float(1.0), unrolled)

    def state(self):
        return (self.down, self.g, self.a, self.has_up, self.hit)

    @staticmethod
    def from_state(s, unrolled=False):
        return MonotoneExit(*s, unrolled=unrolled)

    def push_down(self, l, active):
        """Appends a downward direction of |Λ| = ``l`` where ``active``; False on a non-monotone path or a
        full run (a = n), which ends the walk."""
        self.down, self.a, ok = push_down(self.down, self.a, self.has_up, l, active, self.unrolled)
        return ok

    def _slot(self, i):
        """(slot i in use, |Λ| of its direction, its g — 0 before an upward direction) for the passes."""
        return self.a > i, self.down[i], dr.select(self.has_up, self.g[i], 0.0)

    def columns(self, lambda_x, lambda_y):
        """One pass over the downward run: (column(Λ_x), exit_via_up(Λ_y, Λ_x)), i.e. p_exit(d_0..d_m, x)/H_m
        and p_exit(d_0..d_m, y, x)/H_m for virtual upward x, y (``exit_given_hits``, ``exit_via_up``)."""
        c0 = dr.select(self.has_up, 0.0, 1.0)

        def step(i, carry):
            c, c_x, c_y = carry
            run, li, gi = self._slot(i)
            r_x = 1.0 / (li + lambda_x)
            c_y_new = (li * c_y + gi) / (li + lambda_y)
            return (dr.select(run, (li * c + gi) * r_x, c), dr.select(run, (li * c_x + lambda_y * c_y_new) * r_x, c_x),
                    dr.select(run, c_y_new, c_y))

        c, c_x, _ = over_run(self.n, self.a, step, (c0, mi.Float(0.0), c0), unrolled=self.unrolled)
        return c, c_x

    def column(self, lambda_x):
        """column(Λ_x) alone: the first value of :meth:`columns`, the same bits, without its other two
        recurrences (for a vertex that makes no connection, and ``exit_probability``)."""

        def step(i, carry):
            run, li, gi = self._slot(i)
            return (dr.select(run, (li * carry[0] + gi) * (1.0 / (li + lambda_x)), carry[0]),)

        return over_run(self.n, self.a, step, (dr.select(self.has_up, 0.0, 1.0),), unrolled=self.unrolled)[0]

    def push_up(self, lam, active):
        """Appends an upward direction with Λ = ``lam`` where ``active``; returns H_{m+1}/H_m, the
        probability that it hits the surface again (0 where not active)."""
        was_up = self.has_up

        def step(i, carry):
            c, cont, g = carry[0], carry[1], carry[2:]
            run = self.a > i
            li = self.down[i]
            gi = dr.select(was_up, self.g[i], 0.0)
            c = dr.select(run, (li * c + gi) / (li + lam), c)
            g_i = lam * c
            return (c, dr.select(run, cont + g_i / li, cont)) + g[:i] + (g_i,) + g[i + 1:]

        out = over_run(self.n, self.a, step, (dr.select(was_up, 0.0, 1.0), mi.Float(0.0)) + tuple(self.g),
                       unrolled=self.unrolled)
        cont, g_new = out[1], out[2:]
        good = (cont > 0.0) & dr.isfinite(cont)
        inv = dr.select(good, 1.0 / cont, 0.0)

        def scale(i, g):  # the slots i ≥ a are never read
            return g[:i] + (dr.select(active, g_new[i] * inv, g[i]),) + g[i + 1:]

        self.g = list(over_run(self.n, self.a, scale, tuple(self.g), unrolled=self.unrolled))
        self.hit = dr.select(active, self.hit * dr.select(good, cont, 0.0), self.hit)
        self.has_up = self.has_up | active
        return dr.select(active, cont, 0.0)

    def exit_probability(self, lam):
        """p_exit(d_0..d_m, x) for an upward x with Λ(x) = ``lam``: H_m times the column."""
        return self.hit * self.column(lam)



def run_slots(max_bounces, slots=None):
    """The registers of a downward run: ``slots`` (default ``CONDUCTOR_RUN_SLOTS``), fewer when the bounce
    cap is smaller (a path has at most that many downward directions), all of them when the cap is per
    lane."""
    slots = CONDUCTOR_RUN_SLOTS if slots is None else slots
    if isinstance(max_bounces, int):
        return max(1, min(max_bounces, slots))
    return slots
