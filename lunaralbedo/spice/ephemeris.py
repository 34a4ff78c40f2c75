"""Ephemerides of one image: Sun, spacecraft and orientations as functions of time.

Two sources with the same interface (positions in km, Moon-centred body-fixed;
rotations as matrices; ``et`` in TDB seconds past J2000, scalar or array):

* :class:`TableEphemeris` - the SPICE caches ``spiceinit`` attached to the cube
  (``SunPosition``, ``InstrumentPosition``: J2000 km relative to the target;
  ``BodyRotation``, ``InstrumentPointing``: J2000 -> frame quaternions).  As ISIS:
  body-fixed vector = ConstantRotation . q2m(q(et)) . v_J2000.
* :class:`KernelEphemeris` - spiceypy on loaded kernels: ``spkpos(target, et,
  'J2000', 'LT+S', 'MOON')`` rotated by ``pxform('J2000', body_frame, et)``.
"""
from __future__ import annotations

import numpy as np
import spiceypy

from ..errors import IsisError, SpiceError
from ..isis.labels import IsisLabel
from ..isis.tables import read_table
from . import interp
from .kernels import body_fixed_frame, pool_value, spice_errors

_XYZ = ("J2000X", "J2000Y", "J2000Z")
_VXYZ = ("J2000XV", "J2000YV", "J2000ZV")
_Q = ("J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3")


class Ephemeris:
    """Interface shared by the table and kernel ephemerides."""

    source = "?"
    body_frame = "MOON_ME"

    def sun(self, et):  # pragma: no cover - interface
        raise NotImplementedError

    def spacecraft(self, et):  # pragma: no cover - interface
        raise NotImplementedError

    def body_rotation(self, et):  # pragma: no cover - interface
        raise NotImplementedError

    def instrument_rotation(self, et):  # pragma: no cover - interface
        raise NotImplementedError

    def camera_to_body(self, et):
        """Matrices rotating instrument-frame vectors into the body-fixed frame."""
        b = self.body_rotation(et)
        c = self.instrument_rotation(et)
        return np.einsum("...ij,...kj->...ik", b, c)


class _PositionCache:
    def __init__(self, table, where: str):
        self.kind = str(table.meta.get("CacheType", "Linear"))
        if self.kind == "PolyFunction":
            rec = table.records
            names = table.fields
            self.coeffs = np.array([[r[names[0]], r[names[1]], r[names[2]]] for r in rec[:-1]], dtype=np.float64)
            self.base, self.scale = float(rec[-1][names[0]]), float(rec[-1][names[1]])
            return
        if self.kind not in ("Linear", "HermiteSpline"):
            raise IsisError(f"{where}: unsupported CacheType {self.kind!r} (Linear, HermiteSpline, PolyFunction)")
        self.times = table.column("ET")
        self.pos = table.columns(*_XYZ)
        self.vel = table.columns(*_VXYZ) if all(v in table.fields for v in _VXYZ) else None
        self.time_range = (float(self.times.min()), float(self.times.max()))

    def __call__(self, et):
        if self.kind == "PolyFunction":
            return interp.poly_function(self.coeffs, self.base, self.scale, et)
        if self.kind == "HermiteSpline" and self.vel is not None:
            return interp.interp_hermite(self.times, self.pos, self.vel, et)
        return interp.interp_linear(self.times, self.pos, et)


class _RotationCache:
    def __init__(self, table, where: str):
        if not all(q in table.fields for q in _Q):
            raise IsisError(f"{where}: only quaternion rotation tables are supported (fields {table.fields})")
        self.times = table.column("ET")
        self.quats = table.columns(*_Q)
        const = table.meta.get("ConstantRotation")
        self.constant = np.asarray(const, dtype=np.float64).reshape(3, 3) if const is not None else np.eye(3)

    def __call__(self, et):
        q = interp.interp_quaternions(self.times, self.quats, et)
        return np.einsum("ij,...jk->...ik", self.constant, interp.quat_to_matrix(q))


class TableEphemeris(Ephemeris):
    """Ephemeris from the cube's attached SPICE tables (no kernels needed)."""

    source = "table"

    def __init__(self, label: IsisLabel):
        self.label = label
        where = str(label.path)
        names = label.table_labels()
        for need in ("SunPosition", "InstrumentPosition", "BodyRotation"):
            if need not in names:
                raise IsisError(f"{where}: no {need} table (run with kernels instead)")
        self._sun = _PositionCache(read_table(label, "SunPosition"), f"{where}: SunPosition")
        self._sc = _PositionCache(read_table(label, "InstrumentPosition"), f"{where}: InstrumentPosition")
        self._body = _RotationCache(read_table(label, "BodyRotation"), f"{where}: BodyRotation")
        self._inst = (
            _RotationCache(read_table(label, "InstrumentPointing"), f"{where}: InstrumentPointing")
            if "InstrumentPointing" in names else None
        )
        frames = read_table(label, "BodyRotation").meta.get("ConstantFrames")
        self.body_frame = "MOON_ME" if frames is not None and int(frames[0]) == 31001 else "body frame of the table"

    @property
    def time_range(self) -> tuple[float, float]:
        """ET range (s) covered by the InstrumentPosition cache."""
        return getattr(self._sc, "time_range", (-np.inf, np.inf))

    def sun(self, et):
        return interp.apply(self.body_rotation(et), self._sun(et))

    def spacecraft(self, et):
        return interp.apply(self.body_rotation(et), self._sc(et))

    def body_rotation(self, et):
        return self._body(et)

    def instrument_rotation(self, et):
        if self._inst is None:
            raise IsisError(f"{self.label.path}: no InstrumentPointing table")
        return self._inst(et)


class KernelEphemeris(Ephemeris):
    """Ephemeris from loaded SPICE kernels (the pool must stay loaded while it is used)."""

    source = "kernels"

    def __init__(self, spacecraft: str | int, instrument_frame: str | int | None, where: str, describe: str = ""):
        self.spacecraft_id = str(spacecraft)
        self.where = where
        self.describe = describe
        self.body_frame = body_fixed_frame()
        self._instrument_frame = instrument_frame

    @property
    def instrument_frame(self) -> str:
        """Name of the instrument frame (resolved on first use; SpiceError when unknown)."""
        code = self._instrument_frame
        if code is None:
            raise SpiceError(f"{self.where}: no instrument frame (label Kernels group lacks NaifFrameCode)")
        name = spiceypy.frmnam(int(code)) if isinstance(code, int) else str(code)
        if not name and isinstance(code, int):  # an instrument code that is no frame: its IK's FOV frame (Kaguya MI)
            name = str(pool_value(f"INS{code}_FOV_FRAME", "")).strip()
        if not name or spiceypy.namfrm(name) == 0:
            raise SpiceError(
                f"{self.where}: unknown instrument frame {code} (load the frames kernel that defines it; {self.describe})"
            )
        return name

    def _ctx(self, what: str, et) -> str:
        t = float(np.ravel(et)[0])
        with spice_errors("et2utc"):
            utc = spiceypy.et2utc(t, "ISOC", 3) if pool_value("DELTET/DELTA_AT") is not None else f"ET {t:.3f}"
        return f"{self.where}: {what} at {utc} (ET {t:.6f} s)" + (f"; kernels {self.describe}" if self.describe else "")

    def _each(self, et, fn, shape):
        ets = np.asarray(et, dtype=np.float64)
        out = np.empty(ets.shape + shape)
        for idx in np.ndindex(ets.shape):
            out[idx] = fn(float(ets[idx]))
        return out

    def _position(self, target: str, et):
        def one(t):
            with spice_errors(self._ctx(f"{target} position relative to MOON", t)):
                pos, _lt = spiceypy.spkpos(target, t, "J2000", "LT+S", "MOON")
            return np.asarray(pos)

        return self._each(et, one, (3,))

    def sun(self, et):
        return interp.apply(self.body_rotation(et), self._position("SUN", et))

    def corrections(self) -> tuple[str, bool]:
        """ISIS's aberration correction of the spacecraft position: the IAK's ``INS<code>_LIGHTTIME_CORRECTION``
        and ``INS<code>_SWAP_OBSERVER_TARGET`` (ISIS ``SpicePosition``), else ``LT+S`` seen from the Moon."""
        code = self._instrument_frame
        if not isinstance(code, int):
            return "LT+S", False
        corr = str(pool_value(f"INS{code}_LIGHTTIME_CORRECTION", "LT+S")).strip().upper()
        swap = str(pool_value(f"INS{code}_SWAP_OBSERVER_TARGET", "FALSE")).strip().upper() == "TRUE"
        return corr, swap

    def spacecraft(self, et):
        corr, swap = self.corrections()
        if not swap and corr == "LT+S":
            return interp.apply(self.body_rotation(et), self._position(self.spacecraft_id, et))

        def one(t):
            with spice_errors(self._ctx(f"{self.spacecraft_id} position relative to MOON ({corr})", t)):
                if swap:  # the Moon seen from the spacecraft, reversed
                    return -np.asarray(spiceypy.spkpos("MOON", t, "J2000", corr, self.spacecraft_id)[0])
                return np.asarray(spiceypy.spkpos(self.spacecraft_id, t, "J2000", corr, "MOON")[0])

        return interp.apply(self.body_rotation(et), self._each(et, one, (3,)))

    def _rotation(self, frame: str, et):
        def one(t):
            with spice_errors(self._ctx(f"rotation J2000 -> {frame}", t)):
                return np.asarray(spiceypy.pxform("J2000", frame, t))

        return self._each(et, one, (3, 3))

    def body_rotation(self, et):
        return self._rotation(self.body_frame, et)

    def instrument_rotation(self, et):
        return self._rotation(self.instrument_frame, et)
