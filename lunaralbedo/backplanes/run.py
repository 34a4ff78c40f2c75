"""``lunaralbedo backplanes``: open a Level-1 cube, build its camera, compute and write the backplanes."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from ..camera.build import build_camera
from ..camera.timing import refuse_radar
from ..errors import IsisError
from ..ingest.observation import open_observation
from ..io.geotiff import write_geotiff
from ..isis.labels import IsisLabel, read_label
from .angles import BAND_NAMES
from .compute import Shape, image_backplanes
from .shape import resolve_shape


def camera_geometry(label: IsisLabel, band: int = 1, dem=None, ellipsoid: bool = False, kernels=(), isisdata=None,
                    source: str = "auto") -> tuple[dict[str, np.ndarray], Shape]:
    """Backplanes (float32 per :data:`BAND_NAMES`) of band ``band`` of the cube, and the shape used."""
    nbands = label.shape[0]
    if not 1 <= band <= nbands:
        raise IsisError(f"{label.path}: band {band} out of range 1..{nbands}")
    refuse_radar(label, "no camera model for radar (SAR) geometry, so no backplanes")  # before its kernels or clock
    shape = resolve_shape(label, dem, ellipsoid, isisdata)
    with open_observation(label.path, label.path.stem[:11], kernels, isisdata, source) as obs:
        camera = build_camera(obs.label, obs.ephemeris, obs.code, band=band)
        return image_backplanes(camera, obs.ephemeris, shape), shape


def write_backplanes(cube, out, band: int = 1, dem=None, ellipsoid: bool = False, kernels=(), isisdata=None,
                     source: str = "auto") -> tuple[dict[str, np.ndarray], Shape]:
    """Write the seven phocube-named backplanes of ``cube`` (band ``band``) to the GeoTIFF ``out``."""
    label = read_label(cube)
    planes, shape = camera_geometry(label, band, dem, ellipsoid, kernels, isisdata, source)
    with warnings.catch_warnings():  # a Level-1 image has no georeference
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        write_geotiff(Path(out), np.stack([planes[n] for n in BAND_NAMES]), Affine.identity(), None,
                      nodata=float("nan"), dtype="float32", descriptions=list(BAND_NAMES),
                      tags=[dict(units="degrees", shape=shape.name, band=str(band))] * len(BAND_NAMES))
    return planes, shape
