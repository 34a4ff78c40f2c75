"""Kernel resolution and loading through spiceypy.

Kernels come from two places:

* the label's ``Kernels`` group (what ``spiceinit`` chose), with ISIS variables
  ``$ISISDATA``, ``$base``, ``$<mission>`` resolved against the ISIS data area
  (``--isisdata``, by default the ``ISISDATA`` environment variable: ``$lro/x`` is
  ``<ISISDATA>/lro/x``); relative paths resolve against the label's folder;
* ``--kernels`` arguments: kernel files, folders (searched recursively) or
  meta-kernels (``.tm``).

The spiceypy kernel pool is global state: :class:`KernelPool` clears it on entry
and on exit so that nothing leaks from one cube (or test) to the next.
"""
from __future__ import annotations

import contextlib
import os
import re
import tempfile
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import spiceypy
from spiceypy.utils.exceptions import SpiceyError

from ..errors import SpiceError

#: Load order for a folder of kernels: text kernels first, then binary ones.
_ORDER = {".tls": 0, ".tpc": 1, ".tsc": 2, ".tf": 3, ".ti": 4, ".bpc": 5, ".bsp": 6, ".bc": 7, ".tm": 8,
          ".xpc": 5, ".xsp": 6, ".xc": 7, ".xbc": 7, ".xfr": 7}  # transfer files: converted when loaded
KERNEL_SUFFIXES = tuple(_ORDER)
#: Kernels group keywords that name kernels (in ISIS's load order).
LABEL_KEYS = (
    "LeapSecond", "TargetAttitudeShape", "TargetPosition", "InstrumentPointing", "Instrument",
    "SpacecraftClock", "InstrumentPosition", "InstrumentAddendum", "Frame", "Extra",
)
_NOT_FILES = {"table", "null", "nadir", ""}
_VAR_RE = re.compile(r"^\$(\{)?([A-Za-z0-9_]+)(?(1)\})")


def isisdata_dir(isisdata: str | Path | None = None) -> Path | None:
    """The ISIS data area ``isisdata`` as a path (None when not given; the command line's ``--isisdata``
    defaults to ``$ISISDATA``)."""
    return Path(isisdata).expanduser() if isisdata else None


def resolve_isis_path(text: str, isisdata: Path | None, relative_to: Path) -> Path | None:
    """A label kernel path as a filesystem path (None when a ``$variable`` cannot be resolved)."""
    text = str(text).strip()
    m = _VAR_RE.match(text)
    if not m:
        p = Path(text).expanduser()
        return p if p.is_absolute() else relative_to / p
    var = m.group(2)
    rest = text[m.end():].lstrip("/")
    if var == "ISISDATA":
        root = isisdata
    elif isisdata is not None:
        root = isisdata / var
    else:
        root = None
    return None if root is None else root / rest


def label_kernels(kernels_group, label_path: Path, isisdata: str | Path | None = None):
    """Kernel files named in a label's Kernels group: ``(found, missing)`` lists.

    ``found`` holds existing paths in load order; ``missing`` the label texts that
    did not resolve to a file (unknown ``$variable`` or absent file).
    """
    root = isisdata_dir(isisdata)
    found: list[Path] = []
    missing: list[str] = []
    if kernels_group is None:
        return found, missing
    for key in LABEL_KEYS:
        if key not in kernels_group:
            continue
        values = kernels_group[key]
        values = values if isinstance(values, (list, tuple)) else [values]
        for v in values:
            if v is None or str(v).strip().lower() in _NOT_FILES:
                continue
            p = resolve_isis_path(str(v), root, label_path.parent)
            if p is not None and p.is_file():
                if p not in found:
                    found.append(p)
            else:
                missing.append(str(v))
    return found, missing


def expand_kernel_args(paths: Iterable[str | Path]) -> list[Path]:
    """Files, folders (recursively, text kernels first) and meta-kernels given by the user."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw).expanduser()
        if p.is_dir():
            files = [f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in _ORDER]
            out.extend(sorted(files, key=lambda f: (_ORDER[f.suffix.lower()], str(f))))
        elif p.is_file():
            out.append(p)
        else:
            raise SpiceError(f"{p}: kernel file or folder not found")
    return out


@contextlib.contextmanager
def spice_errors(context: str) -> Iterator[None]:
    """Turn a spiceypy error into :class:`SpiceError` prefixed with ``context``."""
    try:
        yield
    except SpiceyError as exc:
        short = getattr(exc, "short", "") or ""
        msg = (getattr(exc, "long", "") or str(exc)).strip().replace("\n", " ")
        raise SpiceError(f"{context}: {short} {msg}".strip()) from None


class KernelPool:
    """Context manager: a cleared spiceypy pool with ``kernels`` furnished, cleared again on exit.

    DAF transfer files (``.xsp``, ``.xc``, ... as ale's test data and NAIF's archives ship them)
    are converted to binary in a temporary folder for the pool's lifetime (``spice.transfer``).
    """

    def __init__(self, kernels: Sequence[Path], missing: Sequence[str] = ()):
        self.kernels = list(kernels)
        self.missing = list(missing)
        self._tmp = None

    def _loadable(self, k: Path) -> Path:
        from .transfer import is_transfer_file, transfer_to_binary

        if not is_transfer_file(k):
            return k
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="lunaralbedo-kernels-")
        return transfer_to_binary(k, Path(self._tmp.name) / f"{len(os.listdir(self._tmp.name))}_{k.stem}.bin")

    def __enter__(self) -> "KernelPool":
        spiceypy.kclear()
        try:
            for k in self.kernels:
                with spice_errors(f"{k}: cannot load kernel"):
                    spiceypy.furnsh(str(self._loadable(Path(k))))
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        spiceypy.kclear()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def describe(self) -> str:
        """For error messages: which kernels are loaded and which label kernels were not found."""
        txt = f"loaded: {', '.join(p.name for p in self.kernels) or 'none'}"
        if self.missing:
            txt += f"; not found (give --kernels or --isisdata): {', '.join(self.missing)}"
        return txt


def pool_value(name: str, default=None):
    """A kernel-pool variable (numbers as a float or a list of floats, text as str); ``default`` if absent."""
    with spiceypy.no_found_check():
        n, typ, found = spiceypy.dtpool(name)
    if not found:
        return default
    if typ == "N":
        vals = [float(v) for v in spiceypy.gdpool(name, 0, n)]
    else:
        vals = list(spiceypy.gcpool(name, 0, n))
    return vals[0] if n == 1 else vals


def frame_defined(name: str) -> bool:
    """Is frame ``name`` known to SPICE (built in or defined by a loaded FK)?"""
    return spiceypy.namfrm(name) != 0


def body_fixed_frame() -> str:
    """MOON_ME when the Moon frame kernels define it, else IAU_MOON (needs PCK constants)."""
    if frame_defined("MOON_ME"):
        return "MOON_ME"
    return "IAU_MOON"
