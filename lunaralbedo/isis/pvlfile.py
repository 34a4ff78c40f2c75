"""PVL parameter files (ISIS ``PHOPAR``-style) parsed with a grammar that accepts what ISIS writes.

ISIS's own PVL reader accepts ``EndGroup`` / ``EndObject`` as well as ``End_Group`` /
``End_Object``; pvl's strict grammars reject the former.  Rather than editing the
text, the file is parsed with pvl's :class:`~pvl.grammar.ISISGrammar` and, when that
fails, with :class:`EndAggregationGrammar` (pvl's permissive ``OmniGrammar`` whose
aggregation blocks close with ``EndGroup`` / ``EndObject``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pvl
from pvl.grammar import ISISGrammar, OmniGrammar

from ..errors import IsisError
from .labels import value_of


class EndAggregationGrammar(OmniGrammar):
    """OmniGrammar with ``Group ... EndGroup`` and ``Object ... EndObject`` blocks (ISIS accepts both spellings)."""

    group_pref_keywords = ("Group", "EndGroup")
    group_keywords = {"GROUP": "ENDGROUP"}
    object_pref_keywords = ("Object", "EndObject")
    object_keywords = {"OBJECT": "ENDOBJECT"}
    aggregation_keywords = {**group_keywords, **object_keywords}
    reserved_keywords = set(OmniGrammar.reserved_keywords) | {"GROUP", "OBJECT", "ENDGROUP", "ENDOBJECT"}


GRAMMARS = (ISISGrammar, EndAggregationGrammar)


def read_pvl(path: str | Path) -> pvl.PVLModule:
    """Parse a PVL parameter file; :class:`IsisError` naming the file when no grammar accepts it."""
    path = Path(path)
    if not path.is_file():
        raise IsisError(f"{path}: parameter file not found")
    text = path.read_text(encoding="latin-1")
    errors = []
    for grammar in GRAMMARS:
        try:
            return pvl.loads(text, grammar=grammar())
        except Exception as exc:  # pvl raises several lexer/parser exception types
            errors.append(f"{grammar.__name__}: {exc}")
    raise IsisError(f"{path}: cannot parse PVL ({'; '.join(errors)})")


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
