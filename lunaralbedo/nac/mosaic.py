"""``nacmosaic``: LE + RE cubes -> one ideal-camera ISIS cube (``noproj`` + ``lronacjitreg`` + ``handmos``).

Orchestration only (math in :mod:`.ideal`, :mod:`.noproj` and :mod:`.jitreg`).  Each cube is opened
with its kernels (as ``ingest`` does), its camera built, then the kernel pool is
released; the ideal camera uses the LE's ephemeris and timing.  The output label
has an ISIS ``IdealCamera`` Instrument group (see :mod:`lunaralbedo.camera.ideal`),
the LE's Kernels group with absolute paths (its ``NaifFrameCode`` gives the
pointing frame) and a ``NacMosaic`` group recording the inputs and the offset.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..camera.build import build_camera
from ..camera.ideal import IdealSpec
from ..errors import InputError
from ..ingest.observation import open_observation
from ..isis.labels import value_of
from ..isis.pixels import read_rows
from ..isis.write import Quantity, write_cube_rows
from ..spice.kernels import LABEL_KEYS, isisdata_dir, resolve_isis_path
from .ideal import NOPROJ_INSTRUMENTS, blend, ideal_camera, ideal_spec, noproj_spec
from .noproj import NodeMap, SplineRows, resample_rows
from .jitreg import overlap_columns, register
from .jitreg_files import read_offset, write_jitreg


@dataclass
class MosaicResult:
    """What :func:`nac_mosaic` wrote (the ideal camera's numbers are in ``spec``, not repeated here)."""

    path: Path
    shape: tuple[int, int]  # ideal lines, samples
    overlap: tuple[int, int]  # blended columns [start, stop)

    # RE offset applied (pixels, convention of .jitreg), measured by jitreg or given
    sample_offset: float
    line_offset: float
    measured: bool

    spec: IdealSpec
    ideal_source: str = "computed"


def _open_camera(path: Path, kernels, isisdata, source):
    with open_observation(path, path.stem, kernels, isisdata, source) as obs:
        if obs.label.is_map_projected:
            raise InputError(f"{path}: nacmosaic needs Level-1 (camera geometry) cubes, not map-projected ones")
        cam = build_camera(obs.label, obs.ephemeris, obs.code)
        if not cam.is_line_scanner:
            raise InputError(f"{path}: not a line scanner (nacmosaic mosaics the two CCDs of a push-broom camera)")
        return obs.label, cam, obs.ephemeris


def _kernels_group(label, isisdata) -> dict:
    """The label's Kernels group with file names made absolute (the mosaic may live elsewhere)."""
    group = label.group("Kernels", required=False) or {}
    root = isisdata_dir(isisdata)
    out = {}
    for key, v in group.items():
        if key in LABEL_KEYS:
            vals = [str(x) for x in (v if isinstance(v, (list, tuple)) else [v])]
            res = [resolve_isis_path(x, root, label.path.parent) for x in vals]
            vals = [str(r.resolve()) if r is not None and r.is_file() else x for x, r in zip(vals, res)]
            out[key] = vals if len(vals) > 1 else vals[0]
        else:
            out[key] = value_of(v)
    return out


def choose_spec(le_label, le_cam, re_cam, ideal: str = "auto"):
    """``(IdealSpec, source)``: the noproj definition of the LE's instrument (``auto``/``noproj``) or the computed one."""
    if ideal not in ("auto", "noproj", "computed"):
        raise InputError(f"ideal camera: choose auto, noproj or computed, not {ideal!r}")
    inst = le_label.instrument
    key = f"{value_of(inst.get('SpacecraftName', ''))}/{value_of(inst.get('InstrumentId', ''))}".upper()
    if ideal != "computed" and key in NOPROJ_INSTRUMENTS:
        summing = float(value_of(inst.get("SpatialSumming", 1)) or 1)
        return noproj_spec(le_cam, NOPROJ_INSTRUMENTS[key], summing, key), f"noproj definition {key} (the ASP LRO-NAC notes)"
    if ideal == "noproj":
        raise InputError(f"{le_label.path}: no noproj ideal-camera definition for {key} "
                         f"(known: {', '.join(NOPROJ_INSTRUMENTS)}); use --ideal computed")
    return ideal_spec(le_cam, re_cam), "computed from the LE/RE camera models"


def _strip(spline, nodes, columns, block_lines: int) -> np.ndarray:
    """The CCD resampled on ideal ``columns`` ``[c0, c1)`` of all lines (for registration and the overlap)."""
    return np.concatenate([resample_rows(spline, *nodes.coords(l0, min(nodes.shape[0], l0 + block_lines), *columns))
                           for l0 in range(0, nodes.shape[0], block_lines)])


def ideal_label(le_label, cam, spec, lines: int, so: float, lo: float, measured: bool, le: Path, re: Path,
                isisdata, source: str = "computed") -> dict:
    inst = le_label.instrument
    xdep = 1 if abs(spec.sample_axis[0]) >= abs(spec.sample_axis[1]) else 2
    ideal = {
        "SpacecraftName": value_of(inst.get("SpacecraftName", "IdealSpacecraft")), "InstrumentId": "IdealCamera",
        "TargetName": value_of(inst.get("TargetName", "MOON")), "InstrumentType": "LINESCAN",
        "StartTime": inst.get("StartTime"), "EphemerisTime": Quantity(cam.timing.et0, "seconds"),
        "ExposureDuration": Quantity(cam.timing.rate * 1000.0, "milliseconds"),
        "LineExposureDuration": Quantity(cam.timing.rate * 1000.0, "milliseconds"),
        "FocalLength": Quantity(spec.focal_length, "millimeters"), "PixelPitch": Quantity(spec.pitch, "millimeters"),
        "SampleDetectors": spec.samples, "LineDetectors": lines, "FocalPlaneXDependency": xdep,
        "TransX": float(np.sign(spec.sample_axis[0] if xdep == 1 else spec.line_axis[0]) or 1.0),
        "TransY": float(np.sign(spec.line_axis[1] if xdep == 1 else spec.sample_axis[1]) or 1.0),
        "TransX0": spec.x0, "TransY0": spec.y0, "SampleAxis": list(spec.sample_axis), "LineAxis": list(spec.line_axis),
    }
    info = {"LeftCube": str(le), "RightCube": str(re), "SampleOffset": so, "LineOffset": lo,
            "OffsetSource": "jitreg" if measured else "given", "IdealCameraSource": source,
            "OffsetConvention": "feature at RE pixel (x, y) lies at LE pixel (x + SampleOffset, y + LineOffset)"}
    return {"Instrument": ideal, "Kernels": _kernels_group(le_label, isisdata), "NacMosaic": info}


def nac_mosaic(le: str | Path, re: str | Path, out: str | Path, offset: str | Path | tuple | None = None,
               kernels: Sequence[Path] = (), isisdata=None, source: str = "auto", height_m: float = 0.0,
               step: int = 8, jitreg_prefix: str | Path | None = None, ideal: str = "auto",
               block_lines: int = 256) -> MosaicResult:
    """Mosaic the LE and RE cubes of an LRO NAC observation into one ideal-camera ISIS cube.

    ASP's ``lronac2mosaic.py`` (the ASP LRO-NAC notes): both CCDs are resampled onto one
    ideal line-scan camera (ISIS ``noproj``; rays of the ideal camera meet the sphere of
    ``height_m``, then are projected into each CCD), the RE is shifted by the LE/RE offset
    (measured as ASP ``lronacjitreg`` does, or given) and the two are blended with a linear
    ramp across their overlap (ISIS ``handmos`` without a seam).  The ideal camera uses the
    LE's ephemeris and timing; the output label has an ISIS ``IdealCamera`` Instrument
    group, the LE's Kernels group (absolute paths) and a ``NacMosaic`` group recording the
    inputs and the offset.  Pixels are 32-bit reals, ISIS Null outside both CCDs.

    Parameters
    ----------
    le, re : str or Path
        The LE (NACL) and RE (NACR) Level-1 cubes of one observation.
    out : str or Path
        ISIS cube to write.
    offset : str or Path or tuple of float, optional
        The RE offset: a ``jitreg`` JSON, or ``(sample_offset, line_offset)`` in pixels
        (the feature at RE pixel ``(x, y)`` lies at LE pixel ``(x + sample_offset, y +
        line_offset)``).  None: measure it (:func:`lunaralbedo.nac.api.jitreg`'s method).
    kernels : sequence of Path, optional
        Extra SPICE kernels (already expanded), loaded after each label's.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` kernel paths.
    source : {"auto", "table", "kernels"}, default "auto"
        Ephemeris source: the cubes' attached SPICE tables when present, or the kernels.
    height_m : float, default 0.0
        Height of the sphere the ideal rays meet, metres above 1737.4 km (ISIS uses the
        ellipsoid; the DEM's mean height is better).
    step : int, default 8
        Ideal pixels between the nodes where the CCD coordinates are computed exactly
        (interpolated between them).
    jitreg_prefix : str or Path, optional
        Prefix of the ``jitreg`` outputs when the offset is measured; default ``out``
        without its suffix + ``-jitreg``.
    ideal : {"auto", "noproj", "computed"}, default "auto"
        The ideal camera: ISIS ``noproj``'s definition for a known instrument (``auto``
        falls back to ``computed``, ``noproj`` requires it), or one computed from the LE/RE
        camera models.
    block_lines : int, default 256
        Ideal lines resampled at a time (memory only; the output does not depend on it).

    Returns
    -------
    MosaicResult
        ``path`` (the cube written), ``shape`` (ideal ``(lines, samples)``), ``overlap``
        (blended columns ``[start, stop)``), ``sample_offset`` and ``line_offset`` (pixels,
        applied to RE), ``measured`` (True when measured here), ``spec`` (the ideal
        camera's :class:`~lunaralbedo.camera.ideal.IdealSpec`: focal length and pitch in
        mm, samples, boresight) and ``ideal_source`` (which definition was used).

    Raises
    ------
    InputError
        Exit 2: the LE is not a line scanner, the CCDs do not overlap on the ideal camera,
        no window correlated (give ``offset``), an unreadable offset file, or ``ideal``
        invalid or ``"noproj"`` for an instrument without a definition.
    IsisError
        Exit 2: a cube or label that cannot be read.
    SpiceError
        Exit 2: a missing kernel or a time the kernels do not cover.
    """
    le, re, out = Path(le), Path(re), Path(out)
    re_label, re_cam, _ = _open_camera(re, kernels, isisdata, source)
    with open_observation(le, le.stem, kernels, isisdata, source) as obs:
        le_label = obs.label
        le_cam = build_camera(le_label, obs.ephemeris, obs.code)
        if not le_cam.is_line_scanner:
            raise InputError(f"{le}: not a line scanner (nacmosaic mosaics the two CCDs of a push-broom camera)")
        spec, ideal_source = choose_spec(le_label, le_cam, re_cam, ideal)
        ideal_cam = ideal_camera(spec, obs.ephemeris, le_cam)
    shape = (le_cam.lines, spec.samples)
    splines = {k: SplineRows(lambda a, b, lab=lab: read_rows(lab, a, b), lab.shape[1:])
               for k, lab in (("le", le_label), ("re", re_label))}
    maps = {k: NodeMap(ideal_cam, cam, shape, height_m, step=step) for k, cam in (("le", le_cam), ("re", re_cam))}
    both = np.flatnonzero(maps["le"].valid_columns() & maps["re"].valid_columns())
    if both.size == 0:
        raise InputError(f"{le}, {re}: the LE and RE CCDs do not overlap on the ideal camera")
    strip = (max(0, int(both[0]) - 2 * step), min(shape[1], int(both[-1]) + 1 + 2 * step))
    le_strip = _strip(splines["le"], maps["le"], strip, block_lines)
    measured = offset is None
    if measured:
        result = register(le_strip, _strip(splines["re"], maps["re"], strip, block_lines))
        result = dataclasses.replace(result, columns=tuple(c + strip[0] for c in result.columns))
        prefix = Path(jitreg_prefix) if jitreg_prefix else out.with_name(out.stem + "-jitreg")
        s = write_jitreg(prefix, result, le, re)
        so, lo = s["sample_offset"], s["line_offset"]
        if not np.isfinite(so):
            raise InputError(f"{le}, {re}: no LE/RE window correlated; give the offset with --offset")
    elif isinstance(offset, (str, Path)):
        so, lo = read_offset(offset)
    else:
        so, lo = (float(v) for v in offset)
    maps["re"] = NodeMap(ideal_cam, re_cam, shape, height_m, offset=(so, lo), step=step)
    a, b = overlap_columns(le_strip, _strip(splines["re"], maps["re"], strip, block_lines), crop_width=shape[1])
    cols = (a + strip[0], b + strip[0])

    def blocks():
        for l0 in range(0, shape[0], block_lines):
            l1 = min(shape[0], l0 + block_lines)
            le_i, re_i = (resample_rows(splines[k], *maps[k].coords(l0, l1)) for k in ("le", "re"))
            yield blend(le_i, re_i, cols)

    write_cube_rows(out, shape, ideal_label(le_label, ideal_cam, spec, shape[0], so, lo, measured, le, re, isisdata,
                                            ideal_source), blocks())
    return MosaicResult(out, shape, cols, so, lo, measured, spec, ideal_source)
