"""Photometric model registry: one module per reflectance model behind one small interface.

Registered models (settings ``REFLECTANCE_TYPE`` code / TOML ``reflectance`` name):

========  =================  =========================================
code      name               module
========  =================  =========================================
0         ``mosaic``         :mod:`.mosaic` (R = 1)
1         ``lambert``        :mod:`.lambert` (R = cos i)
2         ``lunar-lambert``  :mod:`.lunar_lambert` (eq. 2; fits c1, c2)
========  =================  =========================================

The interface is :class:`~.base.PhotometricModel`.  Adding a model is one new module
that builds a ``MODEL``, one line in :data:`REGISTRY` and its test (worked example in
docs/architecture.md).  The solver, the forward model, the legacy mode, the settings
and the outputs all go through :func:`get`.
"""
from __future__ import annotations

from ...errors import SettingsError
from . import lambert, lunar_lambert, mosaic
from .base import PhotometricModel, SettingSpec

#: Every model, by name, in code order.
REGISTRY: dict[str, PhotometricModel] = {m.name: m for m in (mosaic.MODEL, lambert.MODEL, lunar_lambert.MODEL)}


def get(name_or_code: str | int) -> PhotometricModel:
    """The model called ``name_or_code`` (a registry name, or a legacy REFLECTANCE_TYPE code)."""
    for m in REGISTRY.values():
        if name_or_code == m.name or (isinstance(name_or_code, int) and name_or_code == m.code):
            return m
    raise SettingsError(f"unknown reflectance model {name_or_code!r}; known: {', '.join(names())} "
                        f"(REFLECTANCE_TYPE {', '.join(str(c) for c in codes())})")


def names() -> list[str]:
    return list(REGISTRY)


def codes() -> list[int]:
    return [m.code for m in REGISTRY.values() if m.code is not None]


def declared_settings() -> dict[str, SettingSpec]:
    """Settings keys declared by the models (legacy KEY -> spec), in registry order."""
    out: dict[str, SettingSpec] = {}
    for m in REGISTRY.values():
        out.update(m.settings)
    return out


__all__ = ["PhotometricModel", "REGISTRY", "codes", "declared_settings", "get", "names"]
