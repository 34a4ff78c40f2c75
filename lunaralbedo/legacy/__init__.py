"""PhotometryTK (2012) drop-in mode: reproduce the legacy program's conventions and outputs.

``solve_legacy(settings, out)`` runs the pipeline as the legacy ``reconstruct.sh``
ran it and writes the legacy output tree (``albedo/``, ``error/``, ``DEM/``,
``weightsSum/``, ``exposure/``, ``phase/``, ``costFun/``, ``weight/`` and the
image/tile lists).  See ``docs/legacy.md`` for the conventions and the measured
agreement with the legacy regression gold.
"""
from __future__ import annotations

from .run import solve_legacy

__all__ = ["solve_legacy"]
