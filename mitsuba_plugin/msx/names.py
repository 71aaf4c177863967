"""The core's table of names (src/config.rs, read through ``msx_choice*`` in include/msx.h): the models,
estimators, distributions, surfaces and MIS densities every route and the Dr.Jit engine name, and what each
model supports. Read once at import; ``plugin/parameters.py`` validates scene parameters against it and the
engine (``jit/``) checks its own tables against it.
"""

from ._native import lib

# The BSDF's plugin name, which every message starts with.
PLUGIN = "msx_posfree"


class Choice:
    """One row of the core's table of names (src/config.rs, read through ``msx_choice`` in include/msx.h):
    a name, its code and, for a model, what it supports."""

    __slots__ = ("name", "code", "flags", "surfaces", "bdpt_surfaces", "distributions", "runs")

    def __init__(self, name, code, flags=0, surfaces=(), bdpt_surfaces=(), distributions=(), runs=None):
        self.name, self.code, self.flags = name, code, flags
        self.surfaces, self.bdpt_surfaces, self.distributions, self.runs = (
            surfaces, bdpt_surfaces, distributions, runs)

    @property
    def random_walk(self):
        """``eval`` is one unbiased estimate of a random walk (else a deterministic closed form)."""
        return bool(self.flags & lib.MSX_FLAG_RANDOM_WALK)

    @property
    def per_order(self):
        """Its value splits by scattering order (else the whole value counts as order 1)."""
        return bool(self.flags & lib.MSX_FLAG_PER_ORDER)

    @property
    def exact(self):
        """It estimates the Smith microsurface's multiple-scattering BSDF itself (the reference)."""
        return bool(self.flags & lib.MSX_FLAG_EXACT)

    def __repr__(self):
        return "Choice(%r, %d)" % (self.name, self.code)


def _read_table():
    """{parameter name: [Choice, ...]} in the core's order (the order of the docs)."""
    from ._native import ffi

    def rows(parameter):
        out = []
        c = ffi.new("MsxChoice *")
        for i in range(lib.msx_choice_count(parameter)):
            if lib.msx_choice(parameter, i, c) != lib.MSX_OK:
                raise RuntimeError("msx: the core's table of names has no row %d of parameter %d" % (i, parameter))
            out.append((ffi.string(c.name).decode(), c.code, c.flags, c.surfaces, c.bdpt_surfaces, c.distributions,
                        c.runs))
        return out

    names = {p: ffi.string(lib.msx_choice_parameter(p)).decode() for p in range(lib.MSX_CHOICE_PARAMETERS)}
    raw = {names[p]: rows(p) for p in names}
    by_code = {p: {r[1]: r[0] for r in raw[p]} for p in raw}

    def decode(mask, parameter):
        return tuple(name for code, name in by_code[parameter].items() if mask >> code & 1)

    table = {}
    for parameter, rs in raw.items():
        if parameter == "model":
            table[parameter] = [Choice(n, code, flags, decode(surf, "surface"), decode(bdpt, "surface"),
                                       decode(dist, "distribution"), by_code["model"].get(runs, n))
                                for n, code, flags, surf, bdpt, dist, runs in rs]
        else:
            table[parameter] = [Choice(r[0], r[1]) for r in rs]
    return table


# The core's table of names: every choice of every parameter (src/config.rs; docs/adding-a-model.md).
TABLE = _read_table()
# {name: code} per parameter, in the core's order.
SURFACES = {c.name: c.code for c in TABLE["surface"]}
DISTRIBUTIONS = {c.name: c.code for c in TABLE["distribution"]}
MODELS = {c.name: c.code for c in TABLE["model"]}
ESTIMATORS = {c.name: c.code for c in TABLE["estimator"]}
# {name: Choice} of every model: the surfaces, estimators and distributions it supports, its flags.
MODEL_INFO = {c.name: c for c in TABLE["model"]}
