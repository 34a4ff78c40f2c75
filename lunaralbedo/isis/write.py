"""Write small ISIS3 cubes (attached label, BandSequential, 32-bit Real, LSB) - used for sample data.

Special pixels: NaN values are written as ISIS NULL.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

import datetime as _dt

import numpy as np

from ..io.atomic import atomic_path
from .labels import time_string

ISIS_NULL_REAL = np.frombuffer(np.uint32(0xFF7FFFFB).tobytes(), "<f4")[0]
_LABEL_BYTES = 16384


def _fmt(v: Any) -> str:
    if isinstance(v, (_dt.date, _dt.datetime)):
        return time_string(v)
    if hasattr(v, "units") and hasattr(v, "value") and not isinstance(v, Quantity):  # pvl Quantity
        return f"{_fmt(v.value)} <{v.units}>"
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, Quantity):
        return f"{_fmt(v.value)} <{v.units}>"
    s = str(v)
    if s and all(c.isalnum() or c in "_-./:$+" for c in s) and not s[0] in "-+.":
        return s
    return '"' + s.replace('"', "'") + '"'


class Quantity:
    """A value with units, written as ``value <units>``."""

    def __init__(self, value, units: str):
        self.value, self.units = value, units


def _group(name: str, values: Mapping[str, Any], indent: str = "  ") -> str:
    width = max((len(k) for k in values), default=0)
    body = "".join(f"{indent}  {k:<{width}} = {_fmt(v)}\n" for k, v in values.items())
    return f"{indent}Group = {name}\n{body}{indent}End_Group\n"


def write_cube(path: str | Path, data: np.ndarray, groups: Mapping[str, Mapping[str, Any]]) -> None:
    """Write a float32 cube, ``(lines, samples)`` or ``(bands, lines, samples)``, with extra label groups
    (e.g. Instrument, Kernels, BandBin), atomically."""
    data = np.asarray(data, dtype="<f4")
    if data.ndim == 3:
        write_cube_rows(path, data.shape[1:], groups, list(data), bands=data.shape[0])
    else:
        write_cube_rows(path, data.shape, groups, [data])


def write_cube_rows(path: str | Path, shape: tuple[int, int], groups: Mapping[str, Mapping[str, Any]],
                    blocks: Iterable[np.ndarray], bands: int = 1) -> None:
    """:func:`write_cube` from consecutive blocks of lines (``(n, samples)`` arrays, ``shape[0]`` lines in all,
    band after band when ``bands`` > 1), so that the image never has to be in memory; atomic (temp file +
    rename) like :func:`write_cube`."""
    lines, samples = shape
    core = (
        "Object = IsisCube\n  Object = Core\n"
        f"    StartByte   = {_LABEL_BYTES + 1}\n    Format      = BandSequential\n"
        + _group("Dimensions", {"Samples": samples, "Lines": lines, "Bands": bands}, "    ")
        + _group("Pixels", {"Type": "Real", "ByteOrder": "Lsb", "Base": 0.0, "Multiplier": 1.0}, "    ")
        + "  End_Object\n"
    )
    for name, values in groups.items():
        core += _group(name, values)
    text = core + f"End_Object\n\nObject = Label\n  Bytes = {_LABEL_BYTES}\nEnd_Object\nEnd\n"
    raw = text.encode("ascii")
    if len(raw) > _LABEL_BYTES:
        raise ValueError(f"label of {path} is longer than {_LABEL_BYTES} bytes")
    written = 0
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(raw + b"\0" * (_LABEL_BYTES - len(raw)))
        for block in blocks:
            block = np.asarray(block, dtype="<f4")
            if block.ndim != 2 or block.shape[1] != samples:
                raise ValueError(f"{path}: block of shape {block.shape}, expected (n, {samples})")
            f.write(np.where(np.isfinite(block), block, ISIS_NULL_REAL).astype("<f4").tobytes())
            written += block.shape[0]
        if written != lines * bands:
            raise ValueError(f"{path}: {written} lines written, {lines * bands} expected")