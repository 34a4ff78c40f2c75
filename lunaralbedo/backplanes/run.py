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
    """Compute the photometric angles and ground coordinates of every pixel of a Level-1 cube.

    The backplanes ISIS ``phocube`` computes, from our camera model: for the ground point
    seen at each pixel, unit vectors to the Sun and to the spacecraft give phase
    :math:`g = \\arccos(\\hat l\\cdot\\hat v)`, incidence :math:`i = \\arccos(\\hat n\\cdot\\hat l)`
    and emission :math:`e = \\arccos(\\hat n\\cdot\\hat v)` (Nefian et al.
    (LPSC), eqs. 4-5), for the sphere's radial normal and for the DEM's local normal.

    Parameters
    ----------
    label : IsisLabel
        The cube's label (:func:`lunaralbedo.isis.labels.read_label`).
    band : int, default 1
        Band of the cube (1-based); a push-frame band has its own framelet geometry.
    dem : str or Path or sequence of them, optional
        DEM GeoTIFF(s) or ISIS DEM cube(s) the rays stop on (heights, or radii converted to
        heights above the 1737.4 km sphere).  Default: the label's ``ShapeModel`` when it
        resolves, else the sphere.
    ellipsoid : bool, default False
        Use the 1737.4 km sphere whatever the DEM (ISIS ``usedem=no``).
    kernels : sequence of str or Path, optional
        Extra SPICE kernels, kernel folders or meta-kernels, loaded after the label's.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` paths (kernels, ShapeModel).
    source : {"auto", "table", "kernels"}, default "auto"
        Ephemeris source: the cube's attached SPICE tables when present, or the kernels.

    Returns
    -------
    planes : dict of str to numpy.ndarray
        One float32 ``(lines, samples)`` array per name of :data:`.angles.BAND_NAMES`, as ISIS
        ``phocube`` names them: ``"Phase Angle"``, ``"Emission Angle"``, ``"Incidence
        Angle"`` (sphere normal), ``"Local Emission Angle"``, ``"Local Incidence Angle"``
        (DEM normal, as ISIS ``Camera::GetLocalNormal``), all degrees; ``"Latitude"``
        (planetocentric) and ``"Longitude"`` (0..360 east), degrees.  NaN off the body.
    shape : Shape
        The surface used: ``name`` (``"sphere"`` or the DEM) and ``height_m(lon, lat)``
        (metres above the sphere; None for the sphere).

    Raises
    ------
    IsisError
        Exit 2: ``band`` outside the cube's bands, a label without an Instrument group or
        camera model.
    SpiceError
        Exit 2: a missing kernel or a time the kernels do not cover.
    InputError
        Exit 2: an unreadable DEM.
    """
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
    """Write the seven ``phocube``-named backplanes of a Level-1 cube to a GeoTIFF.

    Computes :func:`camera_geometry` and writes it as a 7-band float32 GeoTIFF in the cube's
    pixel frame (no georeference, NaN no-data), each band described by its ISIS ``phocube``
    name and tagged ``units=degrees``, the shape's name and the cube band.

    Parameters
    ----------
    cube : str or Path
        ISIS3 Level-1 cube (``spiceinit``-ed, or with resolvable kernels).
    out : str or Path
        GeoTIFF to write (atomically).
    band, dem, ellipsoid, kernels, isisdata, source
        As for :func:`camera_geometry`.

    Returns
    -------
    planes, shape
        As :func:`camera_geometry` returns them (the planes also written to ``out``).

    Raises
    ------
    IsisError, SpiceError, InputError
        Exit 2, as for :func:`camera_geometry`; OutputError (exit 2) when ``out`` cannot be written.
    """
    label = read_label(cube)
    planes, shape = camera_geometry(label, band, dem, ellipsoid, kernels, isisdata, source)
    with warnings.catch_warnings():  # a Level-1 image has no georeference
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        write_geotiff(Path(out), np.stack([planes[n] for n in BAND_NAMES]), Affine.identity(), None,
                      nodata=float("nan"), dtype="float32", descriptions=list(BAND_NAMES),
                      tags=[dict(units="degrees", shape=shape.name, band=str(band))] * len(BAND_NAMES))
    return planes, shape
