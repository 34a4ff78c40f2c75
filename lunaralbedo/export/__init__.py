"""Google Earth and GIS export of a RESULTS_DIR (``lunaralbedo export-kml``).

Products: ``albedo_sub4/`` (tiles at 1/4 resolution), ``kml/doc.kml`` (a
multi-level KML superoverlay of RGBA PNG tiles that Google Earth and GDAL's
KMLSUPEROVERLAY driver read) and ``albedo_mosaic.tif`` / ``error_mosaic.tif``
(Cloud-Optimized GeoTIFFs).  See ``docs/export.md``.
"""
from __future__ import annotations

from .api import export_kml

__all__ = ["export_kml"]
