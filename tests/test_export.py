"""export-kml on synthetic float32 results: KML read back through GDAL, stretch, transparency,
sub4, COG mosaics, parallel = serial, re-runs, errors and the CLI."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rio_cogeo.cogeo import cog_validate

from lunaralbedo.cli import main
from lunaralbedo.errors import InputError
from lunaralbedo.export import export_kml
from test_export_common import (
    albedo_fn, all_files, error_fn, expected_dn, kml_vs_albedo, make_result, pixel_centres, read_kml,
    sample_tiles, stretch_of,
)

KML_NS = {"k": "http://www.opengis.net/kml/2.2"}
SIX = [(w, n) for n in (0, -4) for w in (0, 4, 8)]  # 3 x 2 tiles of 4 degrees: lon 0..12, lat -8..0


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    """A 600 x 400 px result (6 tiles of 200 px, with error maps) exported once with defaults."""
    root = make_result(tmp_path_factory.mktemp("six"), SIX, n=200, errors=True)
    return root, export_kml(root, workers=2)


def test_kml_reads_back_through_gdal_with_bounds_size_and_values(six):
    root, summary = six
    assert summary["levels"] == 3 and summary["tiles_per_level"] == [1, 2, 6]
    worst, alpha_ok, facts, rgba = kml_vs_albedo(root)
    assert facts["driver"] == "KMLSUPEROVERLAY" and facts["count"] == 4
    assert facts["bounds"] == pytest.approx((0.0, -8.0, 12.0, 0.0), abs=1e-9)
    assert (facts["width"], facts["height"]) == (600, 400)  # the native grid: one PNG pixel per albedo pixel
    assert worst == 0 and alpha_ok  # finest level = the stretched albedo, exactly
    assert np.array_equal(rgba[0], rgba[1]) and np.array_equal(rgba[0], rgba[2])
    assert facts["overviews"] == [2, 4]


def test_pyramid_pngs_are_compressed_at_the_fast_zlib_level(six):
    """Every PNG of the pyramid, as written, carries the "fast" class of zlib levels (2-5) in its stream
    header's FLEVEL bits, not the "default" class (6) of GDAL's default level, and is one complete stream."""
    import struct
    import zlib

    root, _ = six
    pngs = sorted((root / "kml").rglob("*.png"))
    assert pngs
    for png in pngs:
        data = png.read_bytes()
        pos, idat = 8, b""
        while pos < len(data):  # the PNG chunks: length, type, data, CRC
            n, kind = struct.unpack(">I4s", data[pos:pos + 8])
            if kind == b"IDAT":
                idat += data[pos + 8:pos + 8 + n]
            pos += 12 + n
        assert (idat[1] >> 6) == 1, png  # FLEVEL 1: levels 2-5 (6 gives 2, 1 gives 0)
        zlib.decompress(idat)  # one complete stream


def test_coarser_levels_are_block_means_of_the_albedo(six):
    root, _ = six
    st = stretch_of(root)
    with rasterio.open(root / "kml" / "doc.kml") as ds:
        level1 = ds.read(1, out_shape=(200, 300))  # GDAL serves this from the level-1 PNGs
        level0 = ds.read(1, out_shape=(100, 150))
    with rasterio.open(root / "albedo_mosaic.tif") as m:
        full = m.read(1).astype(float)
    for got, f in ((level1, 2), (level0, 4)):
        means = full.reshape(400 // f, f, 600 // f, f).mean(axis=(1, 3))
        assert np.abs(got.astype(int) - expected_dn(means, st)).max() <= 1


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")  # the PNGs carry no georeferencing
def test_pyramid_files_and_kml_structure(six):
    root, summary = six
    kml = root / "kml"
    pngs = sorted(kml.rglob("*.png"))
    assert len(pngs) == summary["tiles"] == 9
    for p in pngs:
        with rasterio.open(p) as ds:
            assert ds.count == 4 and ds.width <= 256 and ds.height <= 256
    assert not list(kml.rglob("*.aux.xml"))
    tree = ET.parse(kml / "doc.kml").getroot()
    assert tree.get("hint") == "target=moon"
    doc = tree.find("k:Document", KML_NS)
    box = doc.find("k:Region/k:LatLonAltBox", KML_NS)
    assert [float(box.find(f"k:{s}", KML_NS).text) for s in ("west", "south", "east", "north")] == [0, -8, 12, 0]
    links = doc.findall("k:NetworkLink", KML_NS)
    assert [ln.find("k:Link/k:href", KML_NS).text for ln in links] == ["1/0/0.kml", "1/1/0.kml"]
    assert all(ln.find("k:Region/k:Lod/k:minLodPixels", KML_NS).text == "128" for ln in links)
    child = ET.parse(kml / "1" / "0" / "0.kml").getroot().find("k:Document", KML_NS)
    assert child.find("k:GroundOverlay/k:Icon/k:href", KML_NS).text == "0.png"
    assert child.find("k:GroundOverlay/k:drawOrder", KML_NS).text == "1"
    assert {ln.find("k:Link/k:href", KML_NS).text for ln in child.findall("k:NetworkLink", KML_NS)} == {
        "../../2/0/0.kml", "../../2/1/0.kml", "../../2/0/1.kml", "../../2/1/1.kml"}


def test_stretch_is_global_percentiles_and_written_next_to_the_kml(six, tmp_path):
    root, summary = six
    st = stretch_of(root)
    with rasterio.open(root / "albedo_mosaic.tif") as m:
        vals = m.read(1)
    lo, hi = np.percentile(vals[np.isfinite(vals)].astype(np.float64), [2, 98])
    assert (st["lo"], st["hi"], st["method"], st["percentiles"]) == (pytest.approx(lo), pytest.approx(hi), "percentile", [2, 98])
    assert "clip" in st["formula"] and summary["stretch"]["lo"] == st["lo"]
    # a fixed range maps albedo lo -> 0 and hi -> 255 on every tile of every level
    small = make_result(tmp_path, [(0, 0), (4, 0)], n=40)
    export_kml(small, value_range=(0.15, 0.25), tile_size=32, workers=1)
    st2 = stretch_of(small)
    assert (st2["lo"], st2["hi"], st2["method"]) == (0.15, 0.25, "range")
    worst, alpha_ok, facts, _ = kml_vs_albedo(small)
    assert worst == 0 and alpha_ok and len(facts["overviews"]) == 2


def test_transparency_outside_the_data(tmp_path):
    # an L of three tiles (no tile at lon 4..8, lat -8..-4) and a NaN hole in the first tile
    root = make_result(tmp_path, [(0, 0), (4, 0), (0, -4)], n=100, hole=(1.0, -3.0, 2.0, -1.0))
    summary = export_kml(root, tile_size=64, workers=2)
    assert summary["levels"] == 3
    worst, alpha_ok, facts, rgba = kml_vs_albedo(root)
    assert worst == 0 and alpha_ok
    lon, lat = pixel_centres(facts["transform"], facts["height"], facts["width"])
    assert (rgba[3][(lon > 4) & (lat < -4)] == 0).all()  # the missing tile
    assert (rgba[3][(lon > 1) & (lon < 2) & (lat > -3) & (lat < -1)] == 0).all()  # the hole
    assert (rgba[3][(lon < 1) | (lat > -1)] == 255).all()
    # PNG tiles lying wholly in the missing tile are not written at all
    assert summary["tiles_per_level"] == [1, 3, 12]  # of 1, 4 and 16


def test_sub4_is_the_mean_of_4x4_blocks(tmp_path):
    root = make_result(tmp_path, [(0, 0), (4, 0)], n=64, hole=(0.5, -2.5, 1.5, -0.5))
    export_kml(root, workers=1)
    for name in ("tile_0E0N.tif", "tile_4E0N.tif"):
        with rasterio.open(root / "albedo" / name) as src, rasterio.open(root / "albedo_sub4" / name) as sub:
            full = src.read(1).astype(np.float64)
            assert (sub.width, sub.height, sub.dtypes[0]) == (16, 16, "float32")
            assert tuple(sub.bounds) == pytest.approx(tuple(src.bounds))
            assert np.isnan(sub.nodata)
            got = sub.read(1)
            blocks = full.reshape(16, 4, 16, 4)
            n_valid = np.isfinite(blocks).sum(axis=(1, 3))
            with np.errstate(invalid="ignore"):
                want = np.nanmean(blocks, axis=(1, 3)) if n_valid.all() else np.nansum(blocks, axis=(1, 3)) / n_valid
            assert np.array_equal(np.isnan(got), n_valid == 0)
            np.testing.assert_allclose(got[n_valid > 0], want[n_valid > 0], rtol=1e-5)
    assert sorted(p.name for p in (root / "albedo_sub4").iterdir()) == ["tile_0E0N.tif", "tile_4E0N.tif"]
    # legacy sizes: 95 px -> 23 px
    other = make_result(tmp_path / "b", [(0, 0)], n=95)
    export_kml(other, workers=1)
    with rasterio.open(other / "albedo_sub4" / "tile_0E0N.tif") as sub:
        assert (sub.width, sub.height) == (23, 23)


def test_mosaics_are_valid_cogs_with_overviews_and_exact_values(six):
    root, summary = six
    for name, folder, fn in (("albedo_mosaic.tif", "albedo", albedo_fn), ("error_mosaic.tif", "error", error_fn)):
        path = root / name
        valid, errors, _ = cog_validate(str(path))
        assert valid, errors
        with rasterio.open(path) as ds:
            assert (ds.width, ds.height, ds.count, ds.dtypes[0]) == (600, 400, 1, "float32")
            assert tuple(ds.bounds) == pytest.approx((0, -8, 12, 0)) and np.isnan(ds.nodata)
            assert ds.overviews(1) == [2, 4] and ds.block_shapes[0] == (256, 256)
            vals = ds.read(1)
            lon, lat = pixel_centres(ds.transform, ds.height, ds.width)
            half = ds.read(1, out_shape=(200, 300))  # served from the first overview
        np.testing.assert_allclose(half, vals.reshape(200, 2, 300, 2).mean(axis=(1, 3)), rtol=1e-6)
        np.testing.assert_array_equal(vals, sample_tiles(root / folder, lon, lat).astype(np.float32))
        np.testing.assert_allclose(vals, fn(lon, lat), atol=1e-6)
    assert summary["error_mosaic"]["overviews"] == [2, 4]


def test_parallel_output_equals_serial(tmp_path):
    outputs = []
    for i, kw in enumerate([dict(workers=1), dict(workers=2), dict(workers=2, pool="processes")]):
        root = make_result(tmp_path / str(i) / "run", SIX, n=40, errors=True)  # same name: it titles doc.kml
        export_kml(root, tile_size=32, **kw)
        files = all_files(root / "kml") | {"sub4/" + k: v for k, v in all_files(root / "albedo_sub4").items()}
        arrays = []
        for name in ("albedo_mosaic.tif", "error_mosaic.tif"):
            with rasterio.open(root / name) as ds:
                arrays.append(ds.read(1))
        outputs.append((files, arrays))
    assert len(outputs[0][0]) > 30
    for files, arrays in outputs[1:]:
        assert files == outputs[0][0]
        for a, b in zip(arrays, outputs[0][1]):
            np.testing.assert_array_equal(a, b)


def test_distributed_client_gives_the_same_output(tmp_path):
    import distributed
    a = make_result(tmp_path / "a" / "run", SIX, n=40)
    b = make_result(tmp_path / "b" / "run", SIX, n=40)
    export_kml(a, tile_size=32, workers=1)
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=":0") as client:
        export_kml(b, tile_size=32, client=client)
    assert all_files(a / "kml") == all_files(b / "kml")


def test_rerun_overwrites_cleanly(tmp_path):
    root = make_result(tmp_path, SIX, n=40, errors=True)
    export_kml(root, tile_size=32, workers=1)
    assert (root / "kml" / "2").is_dir() and (root / "error_mosaic.tif").exists()
    for p in (root / "error").iterdir():
        p.unlink()
    (root / ".tmp-kml-killedrun" / "0").mkdir(parents=True)  # left by a killed export
    (root / ".tmp-kml-killedrun" / "doc.kml").write_text("stale")
    summary = export_kml(root, levels=1, tile_size=32, workers=1)
    assert summary["levels"] == 1 and summary["error_mosaic"] is None
    assert sorted(p.name for p in (root / "kml").iterdir()) == ["0", "doc.kml", "stretch.json"]
    assert not (root / "error_mosaic.tif").exists()
    assert not [p for p in root.rglob(".tmp-*")]
    _, rgba = read_kml(root)
    assert rgba.shape == (4, 21, 32)  # 120 x 80 px shrunk into one 32-px tile


def test_missing_albedo_is_an_input_error_naming_the_folder(tmp_path):
    with pytest.raises(InputError, match=str(tmp_path / "albedo")):
        export_kml(tmp_path)
    result = CliRunner().invoke(main, ["export-kml", str(tmp_path)])
    assert result.exit_code == 2 and "error:" in result.output and str(tmp_path / "albedo") in result.output


def test_all_nodata_albedo_is_an_input_error(tmp_path):
    make_result(tmp_path, [(0, 0)], n=10, hole=(-1, -5, 5, 1))
    with pytest.raises(InputError, match=f"{tmp_path / 'albedo'}: .*no valid pixel"):
        export_kml(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["albedo"]  # nothing half-written


def test_tiles_with_different_pixel_sizes_are_refused(tmp_path):
    make_result(tmp_path, [(0, 0)], n=40)
    make_result(tmp_path, [(4, 0)], n=50)
    with pytest.raises(InputError, match="share one pixel size.*tile_4E0N"):
        export_kml(tmp_path)


def test_cli_prints_a_summary_and_rejects_conflicting_stretches(tmp_path):
    root = make_result(tmp_path, [(0, 0), (4, 0)], n=40)
    result = CliRunner().invoke(main, ["export-kml", str(root), "--stretch", "p5,p95", "--tile-size", "32", "--workers", "1"])
    assert result.exit_code == 0, result.output
    for word in ("levels", "stretch", "doc.kml", "albedo_mosaic.tif", "time"):
        assert word in result.output
    assert stretch_of(root)["percentiles"] == [5, 95]
    result = CliRunner().invoke(main, ["export-kml", str(root), "--range", "0.1,0.2", "--json", "--levels", "2"])
    assert result.exit_code == 0 and json.loads(result.output)["levels"] == 2
    result = CliRunner().invoke(main, ["export-kml", str(root), "--range", "0,1", "--stretch", "2,98"])
    assert result.exit_code == 2 and "either --stretch or --range" in result.output
    result = CliRunner().invoke(main, ["export-kml", str(root), "--levels", "0"])
    assert result.exit_code == 2 and "--levels" in result.output


def test_fewer_levels_than_needed_average_the_albedo(tmp_path):
    root = make_result(tmp_path, SIX, n=40)  # 120 x 80 px
    summary = export_kml(root, levels=2, tile_size=32, workers=1)
    assert summary["kml_size"] == [64, 42]  # coarser than native
    _, rgba = read_kml(root)
    with rasterio.open(root / "albedo_mosaic.tif") as m:
        ref = m.read(1, out_shape=(42, 64), resampling=rasterio.enums.Resampling.average)
    assert rgba.shape == (4, 42, 64)
    assert np.abs(rgba[0].astype(int) - expected_dn(ref, stretch_of(root))).max() <= 2


def test_mosaic_assembled_from_many_blocks_equals_the_exported_one(six, tmp_path):
    from lunaralbedo.export.mosaic import assemble_cog, block_grids, write_mosaic_block
    from lunaralbedo.export.sources import find_sources, native_grid

    root, _ = six
    sources = find_sources(root / "albedo")
    grid = native_grid(sources)
    blocks = block_grids(grid, 96)  # 7 x 5 blocks with partial last row and column
    assert len(blocks) == 35 and sum(g.width * g.height for _, _, g in blocks) == 600 * 400
    parts = [write_mosaic_block(sources, r0, c0, g, tmp_path / f"b{i}.tif") for i, (r0, c0, g) in enumerate(blocks)]
    info = assemble_cog(parts, grid, sources[0].crs_wkt, tmp_path / "m.tif")
    assert info["valid_pixels"] == 600 * 400 and cog_validate(str(tmp_path / "m.tif"))[0]
    assert not list(tmp_path.glob("b*.tif"))  # scratch blocks removed
    with rasterio.open(tmp_path / "m.tif") as a, rasterio.open(root / "albedo_mosaic.tif") as b:
        np.testing.assert_array_equal(a.read(1), b.read(1))
        assert a.transform.almost_equals(b.transform) and a.crs == b.crs
