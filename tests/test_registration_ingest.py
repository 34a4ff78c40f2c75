"""Registration on `ingest` output: the forward-model mission (sample_data) ingested, its DRGs moved by known shifts."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from bad_input_common import assert_clean_failure, cli
from lunaralbedo.engine.offsets import metres_to_map, pixel_metres, read_offsets_csv
from lunaralbedo.engine.solve import solve
from lunaralbedo.io.drg_levels import write_moved
from lunaralbedo.io.rasters import catalog_drgs
from lunaralbedo.settings import load_settings, replace

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"
CUBES = sorted((SAMPLE / "cubes").glob("*.cub"))
#: pixels (east, north) by which each ingested DRG is moved: the registration must undo them
MOVES = np.array([[1.5, -1.0], [-1.2, 0.8], [0.4, 1.6], [-1.7, -0.3], [0.9, -1.4]])


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("ingested") / "work"
    res = cli("ingest", *CUBES, "--dem", SAMPLE / "dem", "-o", d, "--match-dem")
    assert res.exit_code == 0, res.stderr
    return d


def test_solve_registers_moved_ingest_drgs(work, tmp_path):
    infos = catalog_drgs(work / "DRG")
    truth = {}
    for info, move in zip(infos, MOVES):  # the file now says the image lies `move` pixels east/north of its place
        px = pixel_metres(info)
        dx, dy = metres_to_map(info) @ (move * px)
        write_moved(info.path, Affine.translation(dx, dy) @ info.transform)
        truth[info.key] = -move
    out = tmp_path / "out"
    solve(replace(load_settings(work / "settings.txt"), register_images=1), out=out, workers=1, plots=False)
    found = read_offsets_csv(out / "image_offsets.csv")
    err = np.array([np.array(found[i.key]) / pixel_metres(i) - truth[i.key] for i in infos])
    assert float(np.sqrt(np.mean(err**2))) < 0.4, err  # measured 0.15 px


def test_ingest_register_writes_drgs_with_the_shifts_it_reports(tmp_path):
    plain, moved = tmp_path / "plain", tmp_path / "registered"
    for d, extra in ((plain, ()), (moved, ("--register",))):
        res = cli("ingest", *CUBES, "--dem", SAMPLE / "dem", "-o", d, "--match-dem", *extra)
        assert res.exit_code == 0, res.stderr
    assert "registered" in res.stdout and not (plain / "image_offsets.csv").exists()
    offsets = read_offsets_csv(moved / "image_offsets.csv")
    for info in catalog_drgs(plain / "DRG"):
        off = np.array(offsets[info.key])
        assert np.all(np.abs(off) / pixel_metres(info) < 0.3)  # the mission's images lie where their kernels say
        dx, dy = metres_to_map(info) @ off
        with rasterio.open(moved / "DRG" / info.path.name) as ds, rasterio.open(info.path) as ref:
            assert ds.transform.c == pytest.approx(ref.transform.c + dx, abs=1e-8)  # the CSV has 6 digits: ~1e-5 m
            assert ds.transform.f == pytest.approx(ref.transform.f + dy, abs=1e-8)  # the CSV has 6 digits: ~1e-5 m
            assert np.array_equal(ds.read(), ref.read(), equal_nan=True)


def test_ingest_rejects_a_negative_max_shift(tmp_path):
    out = tmp_path / "w"
    res = cli("ingest", *CUBES, "--dem", SAMPLE / "dem", "-o", out, "--register", "--register-max-shift", "-2")
    assert_clean_failure(res, 2, "--register-max-shift", absent=out)
