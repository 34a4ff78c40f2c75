"""Shared fixtures: where ``../shared`` is, and skipping tests that need it when it is absent."""
from __future__ import annotations

import os
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


@pytest.fixture(scope="session")
def dask_cluster():
    """One local Dask cluster of 2 single-threaded worker processes, shared by the tests that
    run the engine on real workers (``--scheduler`` its address); closed at the end."""
    distributed = pytest.importorskip("distributed")
    from lunaralbedo.engine.executor import _worker_config

    with _worker_config():
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=40)
    yield cluster
    cluster.close()
