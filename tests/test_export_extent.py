"""export-kml covers the data, not whole solver tiles: KML LatLonBox, COG mosaic and sub4."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import rasterio

from lunaralbedo.export import export_kml
from test_export_common import make_result

KML_NS = {"k": "http://www.opengis.net/kml/2.2"}
TILES = [(w, n) for n in (4, 0) for w in (8, 12, 16)]  # 4-degree tiles over lon 8..20, lat -4..4
BOX = (10.0, -2.0, 18.0, 2.0)  # (west, south, east, north)


def blank_outside(root, box) -> None:
    """NaN every albedo pixel whose centre is outside ``box`` (as a solve over a smaller box leaves it)."""
    for p in (root / "albedo").glob("tile_*.tif"):
        with rasterio.open(p, "r+") as ds:
            a = ds.read(1)
            cols, rows = np.meshgrid(np.arange(ds.width) + 0.5, np.arange(ds.height) + 0.5)
            lon, lat = ds.transform * (cols, rows)
            a[(lon < box[0]) | (lon > box[2]) | (lat < box[1]) | (lat > box[3])] = np.nan
            ds.write(a, 1)


def root_latlonbox(root) -> tuple[float, float, float, float]:
    doc = ET.parse(root / "kml" / "doc.kml").getroot()
    box = doc.find(".//k:LatLonBox", KML_NS)
    get = lambda k: float(box.find(f"k:{k}", KML_NS).text)  # noqa: E731
    return get("west"), get("south"), get("east"), get("north")


def check_cropped(root, summary, box) -> None:
    assert summary["bounds"] == pytest.approx(box, abs=1e-9)
    assert root_latlonbox(root) == pytest.approx(box, abs=1e-9)
    with rasterio.open(root / "albedo_mosaic.tif") as ds:
        assert tuple(ds.bounds) == pytest.approx(box, abs=1e-9)
        a = ds.read(1)
        assert np.isfinite(a).mean() == 1.0  # every pixel of the mosaic holds data
    for p in (root / "albedo_sub4").glob("*.tif"):
        with rasterio.open(p) as ds:
            w, s, e, n = ds.bounds
            assert box[0] - 1e-9 <= w < e <= box[2] + 1e-9 and box[1] - 1e-9 <= s < n <= box[3] + 1e-9, p.name


def test_export_is_cropped_to_the_valid_albedo(tmp_path):
    root = make_result(tmp_path, TILES, n=40)
    blank_outside(root, BOX)
    summary = export_kml(root, workers=1)
    check_cropped(root, summary, BOX)
    assert summary["native_size"] == [80, 40]  # 8 x 4 degrees at 0.1 degree, not 12 x 8
    assert summary["sub4_tiles"] == 6


def test_export_is_cropped_to_a_smaller_simulation_box(tmp_path):
    root = make_result(tmp_path, TILES, n=40)  # tiles full of data ...
    (root / "report.json").write_text(json.dumps({"settings": {"simulation_box": [10, 18, -2, 2]}}))  # ... box smaller
    summary = export_kml(root, workers=1)
    check_cropped(root, summary, BOX)


def test_a_tile_without_data_is_left_out(tmp_path):
    root = make_result(tmp_path, TILES, n=40)
    blank_outside(root, (8.0, 0.0, 16.0, 4.0))  # data only in the two north-west tiles
    summary = export_kml(root, workers=1)
    assert summary["bounds"] == pytest.approx((8.0, 0.0, 16.0, 4.0))
    assert sorted(p.name for p in (root / "albedo_sub4").iterdir()) == ["tile_12E4N.tif", "tile_8E4N.tif"]
