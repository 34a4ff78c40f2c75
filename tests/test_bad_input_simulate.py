"""Bad-input matrix of ``simulate`` and a cluster that cannot be reached (``--scheduler`` on a closed port).

``simulate``: a value that cannot make a scene -> exit 2, one line naming the option,
nothing written; an output folder that cannot be created or is not empty -> exit 2
naming it.  A scheduler address where nothing listens -> exit 3 at once (not after
Dask's 20 s connect timeout), one line naming the address, no output folder.
"""
from __future__ import annotations

import socket

import pytest

from bad_input_common import assert_clean_failure, cli
from lunaralbedo.simulate import SceneSpec, render_scene
from test_export_common import make_result


@pytest.mark.parametrize("args, culprit", [
    (["--images", "0"], "--images"),
    (["--size", "2"], "--size"),
    (["--res", "-0.01"], "--res"),
    (["--res", "nan"], "--res"),
    (["--spread", "1.5"], "--spread"),
    (["--noise", "-1"], "--noise"),
    (["--tile-size", "0"], "--tile-size"),
    (["--res", "1", "--size", "120"], "does not fit on the Moon"),
])
def test_values_that_cannot_make_a_scene(tmp_path, args, culprit):
    out = tmp_path / "scene"
    assert_clean_failure(cli("simulate", out, *args), 2, culprit, absent=out)


def test_wrong_type_is_a_usage_error_naming_the_option(tmp_path):
    res = cli("simulate", tmp_path / "scene", "--images", "abc")
    assert res.exit_code == 2 and "--images" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "scene").exists()


def test_output_below_a_regular_file(tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    assert_clean_failure(cli("simulate", blocker / "scene", "--images", "2", "--size", "16"), 2, blocker)
    assert blocker.read_text() == "x"


def test_output_folder_not_empty_is_left_alone(tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    assert_clean_failure(cli("simulate", tmp_path, "--images", "2", "--size", "16"), 2, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_failure_while_rendering_leaves_no_scene_folder(tmp_path, monkeypatch):
    import lunaralbedo.simulate.strip as sim

    def full_disk(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(sim, "write_positions", full_disk)  # after the DEM, truth and DRGs are written
    with pytest.raises(OSError):
        render_scene(tmp_path / "scene", SceneSpec(n_images=2, image_px=16))
    assert not (tmp_path / "scene").exists()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again when the socket is: nothing listens there


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("cluster")
    render_scene(d / "scene", SceneSpec(n_images=2, image_px=24, tile_size=0.5, max_num_iter=1))
    make_result(d / "res", [(0, 0)], n=16)
    return d


@pytest.mark.parametrize("command", ["solve", "export-kml"])
def test_scheduler_that_cannot_be_reached(small_scene, tmp_path, command):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    out = tmp_path / "out"
    args = ([small_scene / "scene" / "settings.txt", "-o", out, "--quiet"] if command == "solve"
            else [small_scene / "res"])
    res = cli(command, *args, "--scheduler", address)
    # "connection refused" comes from the probe, at once; Dask alone would say "Timed out ... after 20 s"
    msg = assert_clean_failure(res, 3, address, "connection refused", absent=out)
    assert "checkpoint" not in msg  # nothing was started, there is nothing to resume
    if command == "export-kml":
        assert not (small_scene / "res" / "kml").exists()
