"""End to end on the real LRO WAC cube: ingest (one DRG per band) -> solve -> export-kml."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
import spiceypy
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.isis.pixels import read_band


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    spiceypy.kclear()


def test_wac_ingest_solve_export(realdata, tmp_path):
    isis = realdata / "isis"
    work = tmp_path / "w"
    run = CliRunner().invoke
    r = run(main, ["ingest", str(isis / "M1181493219CE.vis.odd.reduced.cub"), "--dem",
                   str(isis / "WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.16bit.reduced.cub"), "--mpp", "250",
                   "-o", str(work)])
    assert r.exit_code == 0, r.output
    assert "5 of 5 cubes ingested" in r.output and "push-frame band 5" in r.output
    centers = {}
    for b in range(1, 6):
        with rasterio.open(work / f"DRG/M1181493B0{b}.tif") as ds:
            centers[b] = float(ds.tags(1)["band_center_nm"])
            assert ds.descriptions[0] == f"{centers[b]:g} nm"
            if b == 1:
                v = ds.read(1)
                w, s, e, n = ds.bounds
    assert centers == {1: 415.0, 2: 566.0, 3: 604.0, 4: 643.0, 5: 689.0}
    # band 1's DRG covers what ISIS phocube says band 1 sees (lat/lon backplanes), to a DRG pixel or two
    lat, lon = read_band(isis / "back.reduced.cub", 4), read_band(isis / "back.reduced.cub", 5)
    px = 2 * np.degrees(250 / 1737400)
    assert s == pytest.approx(np.nanmin(lat), abs=px) and n == pytest.approx(np.nanmax(lat), abs=px)
    assert w == pytest.approx(np.nanmin(lon), abs=px) and e == pytest.approx(np.nanmax(lon), abs=px)
    assert np.isfinite(v).sum() > 1000
    r = run(main, ["solve", str(work / "settings.txt"), "-o", str(work / "albedo"), "--workers", "1"])
    assert r.exit_code == 0, r.output
    report = json.loads((work / "albedo/report.json").read_text())
    assert "images used 5" in r.output, report
    r = run(main, ["export-kml", str(work / "albedo"), "--workers", "1"])
    assert r.exit_code == 0, r.output
    assert (work / "albedo/kml/doc.kml").is_file()
    with rasterio.open(work / "albedo/albedo_mosaic.tif") as ds:
        a = ds.read(1, masked=True)
    assert a.count() > 1000 and float(a.min()) > 0
