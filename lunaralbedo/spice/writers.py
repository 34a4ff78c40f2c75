"""Write SPICE kernels with spiceypy (binary SPK type 13, CK type 3) and as text (LSK/PCK/FK/IK/SCLK).

Used to build the synthetic sample mission; every writer replaces its target atomically.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import spiceypy

from ..io.atomic import atomic_path, atomic_write_text


def _value(v) -> str:
    if isinstance(v, str):
        return "'" + v + "'" if not v.startswith("@") else v
    if isinstance(v, (list, tuple, np.ndarray)):
        items = [_value(x) for x in v]
        # SPICE reads at most 132 characters per kernel line: long arrays continue on the next lines
        sep = "\n        " if sum(len(x) + 1 for x in items) > 96 else " "
        return "( " + sep.join(items) + " )"
    return repr(float(v)) if isinstance(v, (float, np.floating)) else str(v)


def write_text_kernel(path: str | Path, kind: str, values: Mapping[str, object], comment: str = "") -> None:
    """A text kernel (``KPL/<kind>``) with ``values`` in a ``\\begindata`` block."""
    width = max(len(k) for k in values)
    body = "".join(f"   {k:<{width}} = {_value(v)}\n" for k, v in values.items())
    atomic_write_text(path, f"KPL/{kind}\n\n{comment}\n\n\\begindata\n\n{body}\n\\begintext\n")


def write_spk(path: str | Path, segments: Sequence[dict], comment: str = "lunaralbedo synthetic SPK") -> None:
    """SPK type 13 (Hermite) segments: dicts with body, center, frame, epochs (N,), states (N, 6) km, km/s."""
    with atomic_path(path) as tmp:
        tmp.unlink()
        handle = spiceypy.spkopn(str(tmp), comment[:60], 0)
        try:
            for seg in segments:
                ep = np.asarray(seg["epochs"], dtype=np.float64)
                st = np.asarray(seg["states"], dtype=np.float64)
                spiceypy.spkw13(handle, int(seg["body"]), int(seg["center"]), seg.get("frame", "J2000"),
                                float(ep[0]), float(ep[-1]), seg.get("segid", "SIM")[:40], int(seg.get("degree", 3)),
                                len(ep), st.tolist(), ep.tolist())
        finally:
            spiceypy.spkcls(handle)


def write_ck(path: str | Path, segments: Sequence[dict], comment: str = "lunaralbedo synthetic CK") -> None:
    """CK type 3 segments: dicts with inst, ref, sclkdp (N,) ticks, quats (N, 4) SPICE (J2000 -> inst)."""
    with atomic_path(path) as tmp:
        tmp.unlink()
        handle = spiceypy.ckopn(str(tmp), comment[:60], 0)
        try:
            for seg in segments:
                t = np.asarray(seg["sclkdp"], dtype=np.float64)
                q = np.asarray(seg["quats"], dtype=np.float64)
                av = np.zeros((len(t), 3))
                spiceypy.ckw03(handle, float(t[0]), float(t[-1]), int(seg["inst"]), seg.get("ref", "J2000"), True,
                               seg.get("segid", "SIM")[:40], len(t), t.tolist(), q.tolist(), av.tolist(), 1, [float(t[0])])
        finally:
            spiceypy.ckcls(handle)
