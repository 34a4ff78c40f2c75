"""Compatibility names: the grid type lives in :mod:`lunaralbedo.model.grid` (one grid for the package)."""
from ..model.grid import Grid, aligned_grid, bilinear, mpp_to_degrees

__all__ = ["Grid", "aligned_grid", "bilinear", "mpp_to_degrees"]
