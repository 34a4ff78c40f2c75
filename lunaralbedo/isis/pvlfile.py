"""The one PVL reader of the package: ISIS3 labels (attached or detached) and parameter files
(ISIS ``PHOPAR``-style), parsed with a grammar that accepts what ISIS writes.

The text is not edited.  It is parsed with pvl's :class:`~pvl.grammar.ISISGrammar` (which joins
the long unquoted words ISIS splits with a trailing ``-`` at the end of a line, e.g. a kernel path
``$lro/kernels/spk/fdf29r_..._v01.b-`` / ``sp``) and, when that fails, with
:class:`EndAggregationGrammar` (pvl's permissive ``OmniGrammar`` whose aggregation blocks close
with ``EndGroup`` / ``EndObject``, the spellings ISIS's own reader accepts besides ``End_Group`` /
``End_Object``).  Of a cube with an attached label only the label is read: the bytes up to its
``End`` line, at most :data:`MAX_LABEL_BYTES`.
"""
from __future__ import annotations

import re
from collections import OrderedDict
from pathlib import Path
from typing import Any

import pvl
from pvl.grammar import ISISGrammar, OmniGrammar

from ..errors import IsisError

#: An attached label ends at a line ``End``; the pixels (or tables) follow.
_END_LINE = re.compile(rb"^End\s*$", re.MULTILINE)
#: Most bytes read for a label (ISIS labels with their history are a few tens of kB).
MAX_LABEL_BYTES = 4 * 1024 * 1024


def value_of(v: Any) -> Any:
    """Strip pvl units (``Quantity``) and return the bare value."""
    return getattr(v, "value", v)


class EndAggregationGrammar(OmniGrammar):
    """OmniGrammar with ``Group ... EndGroup`` and ``Object ... EndObject`` blocks (ISIS accepts both spellings)."""

    group_pref_keywords = ("Group", "EndGroup")
    group_keywords = {"GROUP": "ENDGROUP"}
    object_pref_keywords = ("Object", "EndObject")
    object_keywords = {"OBJECT": "ENDOBJECT"}
    aggregation_keywords = {**group_keywords, **object_keywords}
    reserved_keywords = set(OmniGrammar.reserved_keywords) | {"GROUP", "OBJECT", "ENDGROUP", "ENDOBJECT"}


GRAMMARS = (ISISGrammar, EndAggregationGrammar)


def read_pvl(path: str | Path, what: str = "PVL file") -> pvl.PVLModule:
    """Parse a PVL file (an ISIS label, a parameter file); :class:`IsisError` naming the file when it is
    missing, a folder, or no grammar accepts it (``what`` names the kind of file in the message; the reason
    is one short line, not pvl's dump of the text around the error).

    Parsed files are kept per process, keyed by path, size and modification time (pvl takes ~0.7 s on a
    WAC label, and ``ingest`` reads each label several times); each caller gets its own copy."""
    path = Path(path)
    if path.is_dir():
        raise IsisError(f"{path}: is a folder, not an ISIS cube or {what}")
    if not path.is_file():
        raise IsisError(f"{path}: {what} not found")
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _PARSED:
        _PARSED.move_to_end(key)
        return _copy_pvl(_PARSED[key])
    with open(path, "rb") as f:
        head = f.read(MAX_LABEL_BYTES)
    end = _END_LINE.search(head)
    text = (head[: end.end()] if end else head).decode("latin-1")
    first = None
    for grammar in GRAMMARS:
        try:
            module = pvl.loads(text, grammar=grammar())
            break
        except Exception as exc:  # pvl raises several lexer/parser exception types
            first = first or exc
    else:
        raise IsisError(f"{path}: not an ISIS cube or {what} ({_pvl_reason(first)})")
    _PARSED[key] = module
    while len(_PARSED) > _PARSED_MAX:
        _PARSED.popitem(last=False)
    return _copy_pvl(module)


#: Parsed PVL files kept per process (see :func:`read_pvl`): at most this many.
_PARSED_MAX = 32
_PARSED: OrderedDict = OrderedDict()


def _copy_pvl(value: Any) -> Any:
    """A copy of a parsed PVL tree that keeps repeated keys (``copy.deepcopy`` of pvl's multi-dicts drops
    them: a cube's several ``Table`` objects became one); leaves (numbers, strings, quantities) are shared."""
    if hasattr(value, "items") and hasattr(value, "getall"):
        return type(value)([(k, _copy_pvl(v)) for k, v in value.items()])
    if isinstance(value, list):
        return [_copy_pvl(v) for v in value]
    return value


def _pvl_reason(exc: Exception | None) -> str:
    """One short line for a pvl parse failure (pvl's own message repeats the text around the error)."""
    line = getattr(exc, "lineno", None)
    if line is not None:
        return f"cannot parse line {line}, column {getattr(exc, 'colno', '?')}"
    args = [a for a in getattr(exc, "args", ()) if isinstance(a, str)]
    return f"cannot parse it: {args[-1].splitlines()[0][:80]}" if args else "cannot parse it"


def find_object(module: Any, name: str, where: str):
    """The first object/group ``name`` (case-insensitive) of ``module``; IsisError naming ``where`` if absent."""
    for key, value in module.items():
        if key.casefold() == name.casefold() and hasattr(value, "items"):
            return value
    raise IsisError(f"{where}: no {name} object")


def get_ci(mapping: Any, name: str, default: Any = None) -> Any:
    """Keyword ``name`` of a PVL aggregation compared case-insensitively (ISIS keywords are), units stripped."""
    for key, value in mapping.items():
        if key.casefold() == name.casefold() and not hasattr(value, "items"):
            return value_of(value)
    return default


def groups(mapping: Any, name: str) -> list:
    """All groups called ``name`` (case-insensitive), in file order."""
    return [v for k, v in mapping.items() if k.casefold() == name.casefold() and hasattr(v, "items")]


def plain(aggregation: Any) -> dict:
    """An aggregation as plain values: keywords upper-cased (units stripped); groups/objects as lists
    of plain dicts under their upper-cased name, in file order."""
    out: dict[str, Any] = {}
    for key, value in aggregation.items():
        if hasattr(value, "items"):
            out.setdefault(key.upper(), []).append(plain(value))
        else:
            out[key.upper()] = value_of(value)
    return out


def read_object(path: str | Path, name: str) -> dict:
    """The first object ``name`` of the PVL file ``path`` as :func:`plain` values (IsisError if absent)."""
    return plain(find_object(read_pvl(path), name, str(path)))
