"""Shared fixtures: where ``../shared`` is, and skipping tests that need it when it is absent."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LUNARALBEDO_SHARED", REPO.parent / "shared"))


def _need(sub: str) -> Path:
    path = SHARED / sub
    if not path.exists():
        pytest.skip(f"needs the reference data folder {path} (../shared beside the repository), which is absent")
    return path


@pytest.fixture(scope="session")
def shared() -> Path:
    """The ``../shared`` folder (tests skip with a reason when it is absent)."""
    return _need("")


@pytest.fixture(scope="session")
def photk_tests() -> Path:
    """PhotometryTK regression inputs and gold (``../shared/photk_tests``)."""
    return _need("photk_tests")


@pytest.fixture(scope="session")
def realdata() -> Path:
    """Real ISIS3 cubes, labels and kernels (``../shared/realdata``)."""
    return _need("realdata")


@pytest.fixture
def clean_spice_pool():
    """An empty SPICE kernel pool before and after the test (use with ``pytest.mark.usefixtures``)."""
    import spiceypy

    spiceypy.kclear()
    yield
    spiceypy.kclear()


@pytest.fixture(scope="session")
def demo_results(tmp_path_factory) -> Path:
    """`make demo` (ingest -> solve -> export-kml -> export-web of sample_data) in a temporary folder."""
    out = tmp_path_factory.mktemp("webdemo") / "demo"
    res = subprocess.run([sys.executable, str(REPO / "tools" / "run_demo.py"), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    page = out / "albedo" / "web" / "index.html"
    assert page.as_uri() in res.stdout  # the demo ends by printing the page to open
    return out / "albedo"


@pytest.fixture(scope="session")
def dask_cluster():
    """One local Dask cluster of 2 single-threaded worker processes, shared by the tests that
    run the engine on real workers (``--scheduler`` its address); closed at the end."""
    import distributed  # a dependency of the package (pyproject): missing, the install is broken and the tests fail
    from lunaralbedo.parallel.workers import worker_config

    with worker_config():
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=40)
    yield cluster
    cluster.close()
