"""Which surface a cube's rays stop on: ``--dem``, ``--ellipsoid`` or the label's ``ShapeModel``.

Without either option the cube's ``Kernels/ShapeModel`` is used when it resolves (as
given, relative to the cube's folder, through ``$ISISDATA`` variables, or its file name
beside the cube); otherwise - or when it is ``Null`` - the 1737.4 km sphere.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..ingest.dem import DemMosaic, load_dems
from ..isis.labels import IsisLabel, value_of
from ..spice.kernels import isisdata_dir, resolve_isis_path
from .compute import Shape


def label_shape_model(label: IsisLabel, isisdata=None) -> Path | None:
    """The label's ShapeModel DEM file when it resolves on this machine, else None."""
    k = label.group("Kernels", required=False)
    text = str(value_of(k.get("ShapeModel", "Null"))) if k is not None else "Null"
    if text.strip().lower() in ("null", "ellipsoid", ""):
        return None
    where = label.path.parent
    candidates = [resolve_isis_path(text, isisdata_dir(isisdata), Path.cwd()),
                  resolve_isis_path(text, isisdata_dir(isisdata), where), where / Path(text).name]
    return next((c for c in candidates if c is not None and c.is_file()), None)


def dem_shape(paths) -> Shape:
    """A DEM shape (GeoTIFF or ISIS DEM cube; radius DEMs converted to heights)."""
    mosaic = DemMosaic(load_dems(list(paths)))

    def height(lon, lat):
        h = mosaic.height(lon, lat)
        return np.where(np.isfinite(h), h, np.nan)

    return Shape(name=", ".join(str(s.path) for s in mosaic.sources), height_m=height)


def resolve_shape(label: IsisLabel, dem=None, ellipsoid: bool = False, isisdata=None) -> Shape:
    """The shape for ``label``: sphere if ``ellipsoid``, the given DEM(s), else the label's ShapeModel or the sphere."""
    if ellipsoid:
        return Shape()
    if dem:
        return dem_shape(dem if isinstance(dem, (list, tuple)) else [dem])
    found = label_shape_model(label, isisdata)
    return dem_shape([found]) if found is not None else Shape()
