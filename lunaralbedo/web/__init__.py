"""The web map and run report of a RESULTS_DIR (``lunaralbedo export-web`` / ``lunaralbedo view``).

A static, self-contained site (Leaflet vendored, data as script files and PNG
tiles, no ``fetch``) that opens from ``file://`` and from any static server.
See ``docs/web.md``.
"""
from __future__ import annotations

from .api import export_web

__all__ = ["export_web"]
