"""File-level entry points of the NAC tools (callable from a notebook; the CLI is a thin layer over them)."""
from __future__ import annotations

from pathlib import Path

from .images import read_image
from .jitreg import register
from .jitreg_files import write_jitreg


def jitreg(le: str | Path, re: str | Path, prefix: str | Path, window: int = 32, step: int = 8, search: int = 10,
           crop_width: int = 200, output_log: str | Path | None = None) -> dict:
    """Register RE onto LE (same ideal-camera grid) and write the ``jitreg`` outputs; return the summary dict."""
    le, re = Path(le), Path(re)
    result = register(read_image(le), read_image(re), window=window, step=step, search=search, crop_width=crop_width)
    return write_jitreg(prefix, result, le, re, Path(output_log) if output_log else None)
