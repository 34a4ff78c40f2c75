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
    missing or no grammar accepts it (``what`` names the kind of file in the message)."""
    path = Path(path)
    if not path.is_file():
        raise IsisError(f"{path}: {what} not found")
    with open(path, "rb") as f:
        head = f.read(MAX_LABEL_BYTES)
    end = _END_LINE.search(head)
    text = (head[: end.end()] if end else head).decode("latin-1")
    errors = []
    for grammar in GRAMMARS:
        try:
            return pvl.loads(text, grammar=grammar())
        except Exception as exc:  # pvl raises several lexer/parser exception types
            errors.append(f"{grammar.__name__}: {exc}")
    raise IsisError(f"{path}: cannot parse the {what} as PVL ({'; '.join(errors)})")


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
