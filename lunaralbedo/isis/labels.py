"""ISIS3 labels: attached (label at byte 0 of a ``.cub``) or detached (``.lbl``).

Parsed with pvl, after two repairs of what ISIS writes and pvl 1.3 rejects:

* ``EndGroup`` / ``EndObject`` spellings (ISIS accepts them) become ``End_Group`` / ``End_Object``;
* long unquoted words that ISIS splits with a trailing ``-`` at the end of a line
  (e.g. ``$lro/kernels/spk/fdf29r_..._v01.b-`` / ``sp``) are joined again.

pvl parses a WAC label in ~0.7 s (its date decoding), and ``ingest`` reads each label several
times (bands, the radar check, the resolution, the DRG): parsed files are kept per process,
keyed by path, size and modification time, and each caller gets its own copy.
"""
from __future__ import annotations

import datetime as _dt
import re
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pvl

from ..errors import IsisError

_END_RE = re.compile(rb"^End\s*$", re.MULTILINE)
_ENDAGG_RE = re.compile(r"^(\s*)End(Group|Object)\b", re.MULTILINE | re.IGNORECASE)
_HYPHEN_RE = re.compile(r"(?<=[^\s=,(])-\r?\n\s+")
_MAX_LABEL_BYTES = 4 * 1024 * 1024
#: Parsed PVL files kept per process (see the module docstring): at most this many.
_PARSED_MAX = 32
_PARSED: OrderedDict = OrderedDict()


def repair_pvl_text(text: str) -> str:
    """Apply the two ISIS-to-pvl repairs described in the module docstring."""
    text = _ENDAGG_RE.sub(lambda m: f"{m.group(1)}End_{m.group(2).capitalize()}", text)
    return _HYPHEN_RE.sub("", text)


def parse_pvl_file(path: str | Path) -> pvl.PVLModule:
    """Parse a PVL file (ISIS label, photometric parameter file, ...) tolerantly."""
    path = Path(path)
    if path.is_dir():
        raise IsisError(f"{path}: is a folder, not an ISIS cube or label file")
    if not path.is_file():
        raise IsisError(f"{path}: file not found")
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _PARSED:
        _PARSED.move_to_end(key)
        return _copy_pvl(_PARSED[key])
    with open(path, "rb") as f:
        head = f.read(_MAX_LABEL_BYTES)
    m = _END_RE.search(head)
    raw = head[: m.end()] if m else head
    try:
        module = pvl.loads(repair_pvl_text(raw.decode("latin-1")))
    except Exception as exc:  # pvl raises several lexer/parser exception types
        raise IsisError(f"{path}: not an ISIS cube or PVL label ({_pvl_reason(exc)})") from None
    _PARSED[key] = module
    while len(_PARSED) > _PARSED_MAX:
        _PARSED.popitem(last=False)
    return _copy_pvl(module)


def _copy_pvl(value: Any) -> Any:
    """A copy of a parsed PVL tree that keeps repeated keys (``copy.deepcopy`` of pvl's multi-dicts drops
    them: a cube's several ``Table`` objects became one); leaves (numbers, strings, quantities) are shared."""
    if hasattr(value, "items") and hasattr(value, "getall"):
        return type(value)([(k, _copy_pvl(v)) for k, v in value.items()])
    if isinstance(value, list):
        return [_copy_pvl(v) for v in value]
    return value


def _pvl_reason(exc: Exception) -> str:
    """One short line for a pvl parse failure (pvl's own message repeats the text around the error)."""
    line = getattr(exc, "lineno", None)
    if line is not None:
        return f"cannot parse line {line}, column {getattr(exc, 'colno', '?')}"
    args = [a for a in getattr(exc, "args", ()) if isinstance(a, str)]
    return f"cannot parse it: {args[-1].splitlines()[0][:80]}" if args else "cannot parse it"


def _find(module: Any, name: str) -> Any | None:
    """Depth-first search for the first aggregation (group/object) called ``name``."""
    if not hasattr(module, "items"):
        return None
    for key, value in module.items():
        if key == name and hasattr(value, "items"):
            return value
    for _key, value in module.items():
        if hasattr(value, "items"):
            hit = _find(value, name)
            if hit is not None:
                return hit
    return None


def value_of(v: Any) -> Any:
    """Strip pvl units (``Quantity``) and return the bare value."""
    return getattr(v, "value", v)


def time_string(v: Any) -> str:
    """An ISIS time keyword as a SPICE-parsable UTC string (pvl turns them into datetimes)."""
    if isinstance(v, _dt.datetime):
        return v.replace(tzinfo=None).strftime("%Y-%m-%dT%H:%M:%S.%f")
    if isinstance(v, _dt.date):
        return v.isoformat()
    text = str(v).strip()
    for suffix in ("Z", "+00:00"):
        text = text[: -len(suffix)] if text.endswith(suffix) else text
    return text


@dataclass
class IsisLabel:
    """A parsed ISIS3 label and the facts the rest of the package needs.

    ``path`` is the label file (a ``.cub`` with attached label or a detached ``.lbl``);
    ``data_path`` the file holding the pixels (None when a detached label has none).
    """

    path: Path
    pvl: pvl.PVLModule

    # ---- generic access -------------------------------------------------
    def group(self, name: str, required: bool = True):
        g = _find(self.pvl, name)
        if g is None and required:
            raise IsisError(f"{self.path}: label has no {name} group")
        return g

    def has(self, name: str) -> bool:
        return _find(self.pvl, name) is not None

    def keyword(self, group: str, key: str, default: Any = ..., required: bool = True) -> Any:
        g = self.group(group, required=default is ... and required)
        if g is not None and key in g:
            return value_of(g[key])
        if default is ...:
            raise IsisError(f"{self.path}: {group} group has no {key} keyword")
        return default

    @property
    def cube(self):
        return self.pvl.get("IsisCube", self.pvl)

    # ---- core -------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        """``(bands, lines, samples)`` of the cube."""
        d = self.group("Dimensions")
        return int(d["Bands"]), int(d["Lines"]), int(d["Samples"])

    @property
    def pixel_type(self) -> str:
        return str(self.keyword("Pixels", "Type"))

    @property
    def base_multiplier(self) -> tuple[float, float]:
        px = self.group("Pixels")
        return float(value_of(px.get("Base", 0.0))), float(value_of(px.get("Multiplier", 1.0)))

    @property
    def data_path(self) -> Path | None:
        """The file with the pixels: the cube itself, or what a detached label's ``^Core`` points to."""
        core = self.pvl.get("^Core") or (self.cube.get("^Core") if hasattr(self.cube, "get") else None)
        if core is None:
            return self.path if self.path.suffix.lower() != ".lbl" else None
        name = core[0] if isinstance(core, (list, tuple)) else core
        target = (self.path.parent / str(name))
        return target if target.is_file() else None

    # ---- instrument -------------------------------------------------------
    @property
    def instrument(self):
        return self.group("Instrument")

    @property
    def is_map_projected(self) -> bool:
        return self.has("Mapping")

    @property
    def naif_frame_code(self) -> int | None:
        k = self.group("Kernels", required=False)
        if k is not None and "NaifFrameCode" in k:
            return int(value_of(k["NaifFrameCode"]))
        return None

    @property
    def naif_keywords(self) -> dict[str, Any]:
        """The ``NaifKeywords`` object (IK/IAK values copied by spiceinit), or {}."""
        nk = self.pvl.get("NaifKeywords")
        return {} if nk is None else {k: value_of(v) for k, v in nk.items()}

    def table_labels(self) -> dict[str, Any]:
        """``{table name: Table object}`` for the tables described in the label."""
        out = {}
        for key, value in self.pvl.items():
            if key == "Table" and hasattr(value, "items"):
                out[str(value.get("Name"))] = value
        return out

    def alpha_cube(self) -> tuple[float, float, float, float, int, int] | None:
        """AlphaCube crop ``(start_sample, start_line, end_sample, end_line, beta_samples, beta_lines)``."""
        a = self.group("AlphaCube", required=False)
        if a is None:
            return None
        return (
            float(a["AlphaStartingSample"]), float(a["AlphaStartingLine"]),
            float(a["AlphaEndingSample"]), float(a["AlphaEndingLine"]),
            int(a["BetaSamples"]), int(a["BetaLines"]),
        )

    def to_alpha(self, sample, line):
        """Cube (beta) pixel coordinates (1-based, centre of first pixel = 1) to parent (alpha) ones."""
        a = self.alpha_cube()
        if a is None:
            return sample, line
        s0, l0, s1, l1, ns, nl = a
        return s0 + (sample - 0.5) * (s1 - s0) / ns, l0 + (line - 0.5) * (l1 - l0) / nl

    def from_alpha(self, sample, line):
        """Inverse of :meth:`to_alpha`."""
        a = self.alpha_cube()
        if a is None:
            return sample, line
        s0, l0, s1, l1, ns, nl = a
        return (sample - s0) * ns / (s1 - s0) + 0.5, (line - l0) * nl / (l1 - l0) + 0.5


def read_label(path: str | Path) -> IsisLabel:
    """Read the label of an ISIS3 cube (attached) or of a detached ``.lbl`` file."""
    path = Path(path)
    module = parse_pvl_file(path)
    if "IsisCube" not in module:
        raise IsisError(f"{path}: not an ISIS3 cube label (no IsisCube object)")
    return IsisLabel(path=path, pvl=module)
