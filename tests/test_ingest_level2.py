"""Level-2 (map-projected, Mapping group) cubes are warped onto the DEM grid with rasterio."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import rasterio
import spiceypy

from lunaralbedo.ingest.run import ingest
from lunaralbedo.isis import read_label
from lunaralbedo.isis.write import Quantity, write_cube

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"


def test_level2_cube_warps_back_onto_its_grid(tmp_path):
    spiceypy.kclear()
    w1 = tmp_path / "w1"
    ingest([SAMPLE / "cubes/SIM-F-00001.cub"], [SAMPLE / "dem"], w1, match_dem=True)
    with rasterio.open(w1 / "DRG/SIM-F-00001.tif") as ds:
        v, t = ds.read(1), ds.transform
    # the DRG as an ISIS Level-2 cube: SimpleCylindrical on the 1737.4 km sphere, metres
    m_per_deg = 1737400.0 * math.pi / 180.0
    mapping = {"ProjectionName": "SimpleCylindrical", "CenterLongitude": Quantity(0.0, "degrees"), "TargetName": "Moon",
               "EquatorialRadius": Quantity(1737400.0, "meters"), "PolarRadius": Quantity(1737400.0, "meters"),
               "LatitudeType": "Planetocentric", "LongitudeDirection": "PositiveEast", "LongitudeDomain": 180,
               "PixelResolution": Quantity(t.a * m_per_deg, "meters/pixel"), "Scale": Quantity(1 / t.a, "pixels/degree"),
               "UpperLeftCornerX": Quantity(t.c * m_per_deg, "meters"),
               "UpperLeftCornerY": Quantity(t.f * m_per_deg, "meters")}
    lab = read_label(SAMPLE / "cubes/SIM-F-00001.cub")
    cube = tmp_path / "L2-00001.cub"
    write_cube(cube, v, {"Instrument": dict(lab.instrument), "Kernels": dict(lab.group("Kernels")), "Mapping": mapping})
    report = ingest([cube], [SAMPLE / "dem"], tmp_path / "w2", kernels=[SAMPLE / "kernels"], match_dem=True)
    (res,) = report.done
    assert res.kind == "level2" and res.key == "L2-00001___"
    with rasterio.open(tmp_path / "w2/DRG/L2-00001___.tif") as ds:
        v2, t2 = ds.read(1), ds.transform
    assert t2.almost_equals(t) and v2.shape == v.shape
    ok = np.isfinite(v)
    inner = ok & np.roll(ok, 1, 0) & np.roll(ok, -1, 0) & np.roll(ok, 1, 1) & np.roll(ok, -1, 1)
    np.testing.assert_allclose(v2[inner], v[inner], rtol=1e-4)
    assert spiceypy.ktotal("ALL") == 0
