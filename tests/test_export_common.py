"""Helpers shared by the export tests: synthetic RESULTS_DIRs and an independent reference sampler.

The reference never goes through the code under test: it point-samples the
albedo tiles (first tile by name wins) at given lon/lat and applies the stretch
formula of docs/export.md.
"""
from __future__ import annotations

import glob
import json
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

from lunaralbedo.engine.tiles import tile_name
from lunaralbedo.io.rasters import MOON_CRS
from lunaralbedo.io.geotiff import write_geotiff


def albedo_fn(lon, lat):
    """Smooth, periodic in longitude (continuous across ±180°), defined up to the poles."""
    lon, lat = np.radians(lon), np.radians(lat)
    return 0.15 + 0.05 * np.sin(3 * lon) + 0.04 * np.cos(2 * lat) + 0.02 * np.sin(5 * lat)


def error_fn(lon, lat):
    return 0.01 + 0.001 * np.cos(np.radians(lat))


def make_result(root: Path, corners, n: int = 100, size: float = 4.0, errors: bool = False, hole=None) -> Path:
    """Write float32 tiles ``tile_<w><n>.tif`` of ``albedo_fn`` (NaN inside ``hole`` = (w, s, e, n))."""
    res = size / n
    for west, north in corners:
        t = Affine(res, 0.0, west, 0.0, -res, north)
        lon = west + (np.arange(n) + 0.5) * res
        lat = north - (np.arange(n) + 0.5) * res
        lon2, lat2 = np.meshgrid(lon, lat)
        a = albedo_fn(lon2, lat2).astype(np.float32)
        if hole is not None:
            w, s, e, nn = hole
            a[(lon2 > w) & (lon2 < e) & (lat2 > s) & (lat2 < nn)] = np.nan
        name = tile_name(west, north) + ".tif"
        write_geotiff(root / "albedo" / name, a, t, MOON_CRS, nodata=np.nan)
        if errors:
            write_geotiff(root / "error" / name, error_fn(lon2, lat2).astype(np.float32), t, MOON_CRS, nodata=np.nan)
    return root


def sample_tiles(folder: Path, lon, lat) -> np.ndarray:
    """Point-sample the tiles of ``folder`` at lon/lat (longitudes taken modulo 360); NaN outside data."""
    out = np.full(np.shape(lon), np.nan)
    for f in sorted(glob.glob(str(folder / "tile_*.tif"))):
        with rasterio.open(f) as ds:
            a = ds.read(1).astype(float)
            if ds.count >= 2 and ds.dtypes[0] == "uint8":
                a[ds.read(2) == 0] = np.nan
            t = ds.transform
            dlon = (np.asarray(lon) - t.c) % 360.0
            c = np.floor(dlon / t.a).astype(int)
            r = np.floor((np.asarray(lat) - t.f) / t.e).astype(int)
            inside = (c >= 0) & (c < ds.width) & (r >= 0) & (r < ds.height) & np.isnan(out)
            out[inside] = a[r[inside], c[inside]]
    return out


def pixel_centres(transform, height: int, width: int):
    lon = transform.c + (np.arange(width) + 0.5) * transform.a
    lat = transform.f + (np.arange(height) + 0.5) * transform.e
    return np.meshgrid(lon, lat)


def stretch_of(results: Path) -> dict:
    return json.loads((results / "kml" / "stretch.json").read_text())


def expected_dn(values, st: dict) -> np.ndarray:
    """The documented stretch: round(255 * clip((v - lo) / (hi - lo), 0, 1))."""
    return np.rint(255 * np.clip((values - st["lo"]) / (st["hi"] - st["lo"]), 0, 1))


def read_kml(results: Path):
    """doc.kml through GDAL's KMLSUPEROVERLAY driver: (dataset facts, full-resolution RGBA array)."""
    with rasterio.open(results / "kml" / "doc.kml") as ds:
        facts = dict(driver=ds.driver, bounds=tuple(ds.bounds), width=ds.width, height=ds.height,
                     count=ds.count, transform=ds.transform, overviews=ds.overviews(1))
        return facts, ds.read()


def kml_vs_albedo(results: Path):
    """(max |DN difference| on data, alpha agrees with data everywhere) of the full-res KML read-back."""
    facts, rgba = read_kml(results)
    lon, lat = pixel_centres(facts["transform"], facts["height"], facts["width"])
    ref = sample_tiles(results / "albedo", lon, lat)
    data = np.isfinite(ref)
    diff = np.abs(rgba[0].astype(int) - expected_dn(ref, stretch_of(results)))
    return (float(diff[data].max()) if data.any() else 0.0), bool(np.array_equal(rgba[3] == 255, data)), facts, rgba


def all_files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
