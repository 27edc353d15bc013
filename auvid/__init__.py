"""``import auvid``: the public API, re-exported from :mod:`pipeline` (the library) — load the fitted models of a
run directory or a registry version, predict, simulate, export the physics model.

    import auvid
    models = auvid.load("runs/basin")
    nudot = models["ls"].predict(nu, tau)
"""

from __future__ import annotations

from pipeline import __version__
from pipeline.api import LoadError, Model, ModelSet, load
from pipeline.fossen import FossenModel, load_fossen, load_uuv, write_fossen, write_uuv

__all__ = ["FossenModel", "LoadError", "Model", "ModelSet", "__version__", "load", "load_fossen", "load_uuv",
           "write_fossen", "write_uuv"]
