"""``nacmosaic``: LE + RE cubes -> one ideal-camera ISIS cube (``noproj`` + ``lronacjitreg`` + ``handmos``).

Orchestration only (math in :mod:`.ideal` and :mod:`.jitreg`).  Each cube is opened
with its kernels (as ``ingest`` does), its camera built, then the kernel pool is
released; the ideal camera uses the LE's ephemeris and timing.  The output label
has an ISIS ``IdealCamera`` Instrument group (see :mod:`lunaralbedo.camera.ideal`),
the LE's Kernels group with absolute paths (its ``NaifFrameCode`` gives the
pointing frame) and a ``NacMosaic`` group recording the inputs and the offset.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..camera.build import build_camera
from ..errors import InputError
from ..ingest.observation import open_observation
from ..isis.labels import value_of
from ..isis.pixels import read_band
from ..isis.write import Quantity, write_cube
from ..spice.kernels import LABEL_KEYS, isisdata_dir, resolve_isis_path
from .ideal import blend, ideal_camera, ideal_spec, resample, sample_map
from .jitreg import overlap_columns, register
from .jitreg_files import read_offset, write_jitreg


@dataclass
class MosaicResult:
    path: Path
    sample_offset: float
    line_offset: float
    measured: bool
    spec: object
    shape: tuple[int, int]
    overlap: tuple[int, int]


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


def ideal_label(le_label, cam, spec, lines: int, so: float, lo: float, measured: bool, le: Path, re: Path,
                isisdata) -> dict:
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
            "OffsetSource": "jitreg" if measured else "given",
            "OffsetConvention": "feature at RE pixel (x, y) lies at LE pixel (x + SampleOffset, y + LineOffset)"}
    return {"Instrument": ideal, "Kernels": _kernels_group(le_label, isisdata), "NacMosaic": info}


def nac_mosaic(le: str | Path, re: str | Path, out: str | Path, offset: str | Path | tuple | None = None,
               kernels: Sequence[Path] = (), isisdata=None, source: str = "auto", height_m: float = 0.0,
               step: int = 8, jitreg_prefix: str | Path | None = None) -> MosaicResult:
    """Mosaic the LE and RE cubes into one ideal-camera cube ``out`` (see module docstring).

    ``offset``: a ``jitreg`` JSON, a ``(sample_offset, line_offset)`` pair, or None
    to measure it (outputs then written at ``jitreg_prefix``, default ``OUT`` without
    suffix + ``-jitreg``).  ``height_m``: height (m above 1737.4 km) of the sphere
    the ideal rays meet (ISIS uses the ellipsoid; a mean DEM height is better).
    """
    le, re, out = Path(le), Path(re), Path(out)
    re_label, re_cam, _ = _open_camera(re, kernels, isisdata, source)
    with open_observation(le, le.stem, kernels, isisdata, source) as obs:
        le_label = obs.label
        le_cam = build_camera(le_label, obs.ephemeris, obs.code)
        if not le_cam.is_line_scanner:
            raise InputError(f"{le}: not a line scanner (nacmosaic mosaics the two CCDs of a push-broom camera)")
        spec = ideal_spec(le_cam, re_cam)
        ideal = ideal_camera(spec, obs.ephemeris, le_cam.timing, le_cam.lines)
    shape = (le_cam.lines, spec.samples)
    le_img, re_img = read_band(le_label), read_band(re_label)
    le_i = resample(le_img, *sample_map(ideal, le_cam, shape, height_m, step=step))
    measured = offset is None
    if measured:
        re_i = resample(re_img, *sample_map(ideal, re_cam, shape, height_m, step=step))
        result = register(le_i, re_i)
        prefix = Path(jitreg_prefix) if jitreg_prefix else out.with_name(out.stem + "-jitreg")
        s = write_jitreg(prefix, result, le, re)
        so, lo = s["sample_offset"], s["line_offset"]
        if not np.isfinite(so):
            raise InputError(f"{le}, {re}: no LE/RE window correlated; give the offset with --offset")
    elif isinstance(offset, (str, Path)):
        so, lo = read_offset(offset)
    else:
        so, lo = (float(v) for v in offset)
    re_i = resample(re_img, *sample_map(ideal, re_cam, shape, height_m, offset=(so, lo), step=step))
    cols = overlap_columns(le_i, re_i, crop_width=shape[1])
    mosaic = blend(le_i, re_i, cols)
    write_cube(out, mosaic, ideal_label(le_label, le_cam, spec, shape[0], so, lo, measured, le, re, isisdata))
    return MosaicResult(out, so, lo, measured, spec, shape, cols)
