"""ISIS3 cubes without ISIS: labels (pvl), attached tables (NumPy) and pixels (rasterio/GDAL)."""
from .labels import IsisLabel, read_label
from .tables import read_table

__all__ = ["IsisLabel", "read_label", "read_table"]
