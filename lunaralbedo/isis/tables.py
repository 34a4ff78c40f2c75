"""Attached ISIS3 tables (e.g. the SPICE caches written by ``spiceinit``) as NumPy records.

A table is described in the label (``Object = Table``: Name, StartByte (1-based),
Bytes, Records, ByteOrder and one ``Group = Field`` per column) and stored as
packed binary records inside the cube file.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import IsisError
from .labels import IsisLabel, value_of

_TYPES = {"double": "f8", "real": "f4", "integer": "i4", "text": "S", "byte": "u1", "unsignedinteger": "u4"}


@dataclass
class IsisTable:
    """One table: its label keywords (``meta``) and its records (structured array)."""

    name: str
    meta: dict[str, Any]
    records: np.ndarray
    fields: list[str] = field(default_factory=list)

    def column(self, name: str) -> np.ndarray:
        return np.asarray(self.records[name], dtype=np.float64)

    def columns(self, *names: str) -> np.ndarray:
        """Stack columns into an ``(N, len(names))`` float64 array."""
        return np.stack([self.column(n) for n in names], axis=-1)


def _dtype(obj, byteorder: str, where: str) -> np.dtype:
    parts = []
    for key, grp in obj.items():
        if key != "Field":
            continue
        ftype = str(grp["Type"]).lower()
        size = int(value_of(grp.get("Size", 1)))
        if ftype not in _TYPES:
            raise IsisError(f"{where}: unsupported table field type {grp['Type']!r}")
        code = _TYPES[ftype]
        if code == "S":
            parts.append((str(grp["Name"]), f"S{size}"))
        else:
            parts.append((str(grp["Name"]), byteorder + code, (size,) if size > 1 else ()))
    return np.dtype(parts)


def read_table(label: IsisLabel, name: str) -> IsisTable:
    """Read table ``name`` from the cube described by ``label``.

    Raises :class:`IsisError` naming the file when the table is absent or its bytes
    are not in the file (e.g. a detached label whose cube is not there).
    """
    objs = label.table_labels()
    if name not in objs:
        raise IsisError(f"{label.path}: no {name} table in the label (tables: {', '.join(objs) or 'none'})")
    obj = objs[name]
    data_path = label.data_path
    if data_path is None:
        raise IsisError(f"{label.path}: table {name} is described but the label has no pixel/table file")
    byteorder = "<" if str(obj.get("ByteOrder", "Lsb")).lower().startswith("lsb") else ">"
    dt = _dtype(obj, byteorder, f"{label.path}: table {name}")
    nrec = int(obj["Records"])
    start = int(obj["StartByte"]) - 1
    with open(data_path, "rb") as f:
        f.seek(start)
        raw = f.read(nrec * dt.itemsize)
    if len(raw) != nrec * dt.itemsize:
        raise IsisError(f"{data_path}: table {name} is truncated (needs {nrec * dt.itemsize} bytes at byte {start + 1})")
    meta = {k: value_of(v) for k, v in obj.items() if k != "Field"}
    return IsisTable(name=name, meta=meta, records=np.frombuffer(raw, dtype=dt), fields=list(dt.names))


def has_table(label: IsisLabel, name: str) -> bool:
    """Is table ``name`` described and readable (its bytes present)?"""
    try:
        read_table(label, name)
        return True
    except IsisError:
        return False
