"""Vectorized variants, both routes: the parameters of ``msx_posfree`` in ``llvm_*`` and ``cuda_*``: ``parameters.Config``
reads constant textures as Python floats (as in scalar variants); these wrappers let it do so on Dr.Jit
arrays of width 1, then hand back the textures themselves. Shared by the Dr.Jit engine's class (``jit_bsdf.py``)
and the batched route (``vectorized.py``)."""

from .parameters import Config
from .base import SPECTRAL_TEXTURES


class ScalarTex:
    """Wraps a texture so that parameters.Config's scalar checks (``float(tex.eval_1(si))``)
    work with LLVM arrays; unwrapped again right after parsing."""

    def __init__(self, tex):
        self.tex = tex

    def eval_1(self, si, active=True):
        return _scalar(self.tex.eval_1(si, active))

    def __getattr__(self, name):
        return getattr(self.tex, name)


class _Props:
    """mi.Properties seen by parameters.Config (textures wrapped by _ScalarTex)."""

    def __init__(self, props):
        self._p = props

    def __contains__(self, name):
        return name in self._p

    def get_texture(self, *args, **kw):
        return ScalarTex(self._p.get_texture(*args, **kw))

    def get_unbounded_texture(self, *args, **kw):
        return ScalarTex(self._p.get_unbounded_texture(*args, **kw))

    def __getattr__(self, name):
        return getattr(self._p, name)


def _scalar(v):
    return float(v[0]) if hasattr(v, "__len__") and len(v) == 1 else v


class _Mi:
    """The mitsuba module seen by parameters.Config: ``traverse(obj)[key]`` gives
    Python floats for width-1 arrays (as in scalar variants)."""

    def __init__(self, mi):
        self._mi = mi

    def traverse(self, obj):
        params = self._mi.traverse(obj)

        class _P:
            def __getitem__(self, key):
                return _scalar(params[key])

        return _P()

    def __getattr__(self, name):
        return getattr(self._mi, name)


def _unwrap(cfg):
    for name in ("alpha_u", "alpha_v") + SPECTRAL_TEXTURES:
        v = getattr(cfg, name, None)
        if isinstance(v, ScalarTex):
            setattr(cfg, name, v.tex)
    return cfg



def vectorized_config(mi, props):
    """The parsed and validated parameters, textures as Mitsuba textures."""
    return _unwrap(Config(_Mi(mi), _Props(props)))
