"""lunaralbedo: calibrated albedo maps of the Moon from orbital images.

Python API (the CLI is a thin layer over it)::

    import lunaralbedo
    result = lunaralbedo.solve("settings.txt", out="albedo_run")

Units and frames everywhere: positions in km, Moon-centred body-fixed; DEM heights
in metres above the 1737.4 km sphere; longitude/latitude in degrees.

Importing the package changes nothing process-wide: numba's vector width (:mod:`.simd`) and the
malloc tuning of worker processes (:mod:`.parallel.workers`) are the command line's choices, or the
caller's (:class:`.runtime.Runtime`).
"""
from __future__ import annotations

__version__ = "0.1.0"

from .errors import LunarAlbedoError  # noqa: E402
from .runtime import Runtime  # noqa: E402

__all__ = ["__version__", "LunarAlbedoError", "Runtime", "Settings", "load_settings", "solve"]


def __getattr__(name: str):
    """``Settings`` and ``load_settings`` on first use: importing the package loads no numba kernel (the command
    line sets numba's vector width first, :mod:`.simd`)."""
    if name in ("Settings", "load_settings"):
        from . import settings

        return getattr(settings, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def solve(*args, **kwargs):
    """Solve for albedo, exposures and phase coefficients; see :func:`lunaralbedo.engine.solve.solve`."""
    from .engine.solve import solve as _solve

    return _solve(*args, **kwargs)
