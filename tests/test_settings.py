"""Settings files: legacy text and TOML, validation messages."""
from __future__ import annotations

from pathlib import Path

import pytest

from lunaralbedo.errors import SettingsError
from lunaralbedo.settings import load_settings

LEGACY = """# Files/directories
DRG_DIR                   drg
DEM_DIR                   dem
SUN_POSITION_FILE         meta/sun.txt   # trailing comment
SPACECRAFT_POSITION_FILE  meta/sc.txt
NUM_PROCESSES             4
TILE_SIZE                 4.0
SIMULATION_BOX            6 : 10 : -10 : -9 # lon_min:lon_max:lat_min:lat_max
REFLECTANCE_TYPE          2
SHADOW_THRESH             40
SHADOW_TYPE               1
TR_CONST                  1.5
PHASE_COEFF_C1            1.4
PHASE_COEFF_C2            0.5
MAX_NUM_ITER              2
NO_DEM_DATA_VAL           -32767
USE_WEIGHTS               1
USE_NORMALIZED_COST_FUN   1
COMPUTE_ERRORS            1
"""


def write(tmp_path: Path, text: str, name: str = "s.txt") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_legacy_file_parses_with_spaces_comments_and_relative_paths(tmp_path):
    s = load_settings(write(tmp_path, LEGACY))
    assert s.simulation_box == (6.0, 10.0, -10.0, -9.0)
    assert s.drg_dir == tmp_path / "drg"
    assert s.sun_position_file == tmp_path / "meta" / "sun.txt"
    assert (s.reflectance_type, s.max_num_iter, s.use_normalized_cost_fun, s.num_processes) == (2, 2, 1, 4)
    assert s.phase_coeff_c1 == 1.4 and s.tr_const == 1.5


def test_toml_equals_legacy(tmp_path):
    toml = """
drg_dir = "drg"
dem_dir = "dem"
sun_position_file = "meta/sun.txt"
spacecraft_position_file = "meta/sc.txt"
num_processes = 4
tile_size = 4.0
simulation_box = "6:10:-10:-9"
reflectance_type = 2
shadow_thresh = 40
shadow_type = 1
tr_const = 1.5
phase_coeff_c1 = 1.4
phase_coeff_c2 = 0.5
max_num_iter = 2
no_dem_data_val = -32767
use_weights = 1
use_normalized_cost_fun = 1
compute_errors = 1
"""
    a = load_settings(write(tmp_path, LEGACY))
    b = load_settings(write(tmp_path, toml, "s.toml"))
    assert a == b


def test_empty_values_allowed_in_mosaic_mode(tmp_path):
    text = "DRG_DIR d\nDEM_DIR\nSUN_POSITION_FILE  \nSPACECRAFT_POSITION_FILE\nREFLECTANCE_TYPE 0\nSIMULATION_BOX 6:10:-10:-9\n"
    s = load_settings(write(tmp_path, text))
    assert s.dem_dir is None and s.reflectance_type == 0 and not s.needs_geometry


def test_legacy_whole_moon_box_is_clamped_to_valid_latitudes(tmp_path):
    s = load_settings(write(tmp_path, "DRG_DIR d\nREFLECTANCE_TYPE 0\nSIMULATION_BOX -180:180:-180:180\n"))
    assert s.simulation_box == (-180.0, 180.0, -90.0, 90.0)


@pytest.mark.parametrize(
    "line, words",
    [
        ("FOO_BAR 3", ["unknown key 'FOO_BAR'", "allowed keys", "DRG_DIR"]),
        ("REFLECTANCE_TYPE 5", ["REFLECTANCE_TYPE", "one of 0, 1, 2"]),
        ("SHADOW_TYPE x", ["SHADOW_TYPE", "one of 0, 1, 2, 3"]),
        ("USE_WEIGHTS 2", ["USE_WEIGHTS", "one of 0, 1"]),
        ("SIMULATION_BOX 1:2:3", ["SIMULATION_BOX", "lon_min:lon_max:lat_min:lat_max"]),
        ("SIMULATION_BOX 6:10:-9:-10", ["lat_min < lat_max"]),
        ("SIMULATION_BOX 6:6:-10:-9", ["lon_min < lon_max"]),
        ("SIMULATION_BOX -190:180:-10:-9", ["more than 360 degrees"]),
        ("TILE_SIZE -4", ["TILE_SIZE", "> 0"]),
        ("MAX_NUM_ITER 2.5", ["MAX_NUM_ITER", "int"]),
        ("REFINE_DEM_INPUT_BLUR wide", ["REFINE_DEM_INPUT_BLUR", "float or auto"]),
        ("REFINE_DEM_INPUT_BLUR -1", ["REFINE_DEM_INPUT_BLUR", ">= 0 (or auto)"]),
    ],
)
def test_invalid_values_name_key_and_allowed_values(tmp_path, line, words):
    text = "DRG_DIR d\nREFLECTANCE_TYPE 0\n" + line + "\n" if not line.startswith("REFLECTANCE") else "DRG_DIR d\n" + line + "\n"
    with pytest.raises(SettingsError) as exc:
        load_settings(write(tmp_path, text))
    for w in words:
        assert w in str(exc.value)
    assert str(tmp_path / "s.txt") in str(exc.value)


@pytest.mark.parametrize("value, want", [("", "auto"), ("auto", "auto"), ("AUTO", "auto"), ("2.5", 2.5)])
def test_refine_dem_input_blur_is_estimated_unless_stated(tmp_path, value, want):
    s = load_settings(write(tmp_path, f"DRG_DIR d\nREFLECTANCE_TYPE 0\nREFINE_DEM_INPUT_BLUR {value}\n"))
    assert s.refine_dem_input_blur == want
    assert "REFINE_DEM_INPUT_BLUR" not in s.to_legacy_text() or want != "auto"  # the default is not pinned in a file


@pytest.mark.parametrize("box", ["170:190:-1:1", "170:-170:-1:1", "-190:-170:-1:1"])
def test_a_box_across_the_antimeridian_is_kept_in_continuous_longitudes(tmp_path, box):
    s = load_settings(write(tmp_path, f"DRG_DIR d\nREFLECTANCE_TYPE 0\nSIMULATION_BOX {box}\n"))
    lon0, lon1, lat0, lat1 = s.simulation_box
    assert (lon1 - lon0, lat0, lat1) == (20.0, -1.0, 1.0)  # 20 degrees wide, not 340
    assert lon0 % 360.0 == 170.0


def test_geometry_required_for_lunar_lambert(tmp_path):
    with pytest.raises(SettingsError, match="DEM_DIR is required by the lunar-lambert reflectance model"):
        load_settings(write(tmp_path, "DRG_DIR d\nREFLECTANCE_TYPE 2\n"))


def test_duplicate_key_and_unknown_toml_key(tmp_path):
    with pytest.raises(SettingsError, match="given twice"):
        load_settings(write(tmp_path, "DRG_DIR d\nDRG_DIR e\nREFLECTANCE_TYPE 0\n"))
    with pytest.raises(SettingsError, match="unknown key 'COLOUR'"):
        load_settings(write(tmp_path, 'drg_dir = "d"\nreflectance_type = 0\ncolour = 1\n', "s.toml"))


def test_missing_settings_file(tmp_path):
    with pytest.raises(SettingsError, match="settings file not found"):
        load_settings(tmp_path / "nope.txt")


def test_photk_settings_files_parse(photk_tests):
    s1 = load_settings(photk_tests / "photometry_settings_1.txt")
    s2 = load_settings(photk_tests / "photometry_settings_2.txt")
    assert s1.simulation_box == s2.simulation_box == (6.0, 10.0, -10.0, -9.0)
    assert s1.reflectance_type == 2 and s2.reflectance_type == 0 and s2.dem_dir is None


@pytest.mark.parametrize("toml_line, code", [('reflectance = "mosaic"', 0), ('reflectance = "lambert"', 1),
                                             ('reflectance = "lunar-lambert"', 2), ("reflectance_type = 1", 1)])
def test_toml_names_the_reflectance_model(tmp_path, toml_line, code):
    geometry = 'dem_dir = "dem"\nsun_position_file = "s.txt"\nspacecraft_position_file = "c.txt"\n'
    s = load_settings(write(tmp_path, f'drg_dir = "d"\n{geometry}{toml_line}\n', "s.toml"))
    assert s.reflectance_type == code and s.model.code == code
    # the legacy rendering maps the model back onto REFLECTANCE_TYPE, and parses to the same settings
    again = load_settings(write(tmp_path, s.to_legacy_text(), "again.txt"))
    assert again.model is s.model and again.initial_params.tolist() == s.initial_params.tolist()
    assert f"REFLECTANCE_TYPE          {code}\n" in s.to_legacy_text()


def test_unknown_reflectance_model_is_named(tmp_path):
    with pytest.raises(SettingsError, match="REFLECTANCE must be one of mosaic, lambert, lunar-lambert, hapke, got 'hapke2'"):
        load_settings(write(tmp_path, 'drg_dir = "d"\nreflectance = "hapke2"\n', "s.toml"))


def test_model_declared_settings_are_read_as_attributes(tmp_path):
    s = load_settings(write(tmp_path, LEGACY.replace("PHASE_COEFF_C1            1.4", "PHASE_COEFF_C1 1.25")))
    assert s.phase_coeff_c1 == 1.25 and s.initial_params.tolist() == [1.25, 0.5]
    assert s.to_dict()["phase_coeff_c1"] == 1.25


@pytest.mark.parametrize("extra, reflectance, expected", [
    ("", 2, True),  # default: on whenever a DEM is used
    ("", 1, True),
    ("CAST_SHADOWS 0\n", 2, False),
    ("CAST_SHADOWS 1\n", 2, True),
])
def test_cast_shadows_default_on_with_a_dem(tmp_path, extra, reflectance, expected):
    p = tmp_path / "s.txt"
    p.write_text(LEGACY.replace("REFLECTANCE_TYPE          2", f"REFLECTANCE_TYPE {reflectance}") + extra)
    assert load_settings(p).uses_cast_shadows is expected


def test_cast_shadows_toml_and_mosaic(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('drg_dir = "drg"\ndem_dir = "dem"\nsun_position_file = "s"\nspacecraft_position_file = "c"\n'
                 "cast_shadows = false\n")
    assert load_settings(p).uses_cast_shadows is False
    p.write_text('drg_dir = "drg"\nreflectance_type = 0\ncast_shadows = true\n')
    assert load_settings(p).uses_cast_shadows is False  # mosaic mode has no DEM
    p.write_text('drg_dir = "drg"\ncast_shadows = 2\n')
    with pytest.raises(SettingsError, match="CAST_SHADOWS must be one of 0, 1"):
        load_settings(p)
