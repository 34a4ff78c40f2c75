"""Typed errors where they happen: raster failures naming the file, and output folders checked up front.

``with open_quietly(path, "DEM") as ds:`` is the one way to open a raster for reading: no
``NotGeoreferencedWarning`` for an image without a georeference (a Level-1 cube, a backplane),
and a file GDAL cannot open or read becomes one typed error naming it.

``with raster_errors(path):`` around a read (or ``raster_errors(path, "write")`` around a
write) turns a truncated or corrupt raster into :class:`~lunaralbedo.errors.InputError`,
a full disk into :class:`~lunaralbedo.errors.DiskFullError` and any other write failure
into :class:`~lunaralbedo.errors.OutputError`, each naming ``path``.
"""
from __future__ import annotations

import contextlib
import warnings
from pathlib import Path
from typing import Iterator

import rasterio
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError

from ..errors import DiskFullError, InputError, LunarAlbedoError, OutputError, typed_error

try:  # rasterio's GDAL error classes (CPLE_*) do not derive from RasterioError
    from rasterio._err import CPLE_BaseError
except ImportError:  # pragma: no cover - private module moved
    CPLE_BaseError = RasterioError


@contextlib.contextmanager
def raster_errors(path: str | Path, action: str = "read") -> Iterator[None]:
    """Re-raise GDAL/rasterio (and OS) errors inside the block as typed errors naming ``path``."""
    try:
        yield
    except LunarAlbedoError:
        raise
    except (RasterioError, CPLE_BaseError, OSError) as exc:
        raise _raster_error(exc, Path(path), action) from None


@contextlib.contextmanager
def open_quietly(path: str | Path, what: str = "raster", error: type[LunarAlbedoError] = InputError) -> Iterator:
    """``rasterio.open(path)`` for reading, for the ``with`` block, without GDAL's warning about a missing
    georeference; a file GDAL cannot open (or a read in the block that fails) raises
    ``error("<path>: cannot open <what>: <GDAL's reason>")``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                yield ds
    except RasterioIOError as exc:
        raise error(f"{path}: cannot open {what}: {exc}") from None


def _raster_error(exc: BaseException, path: Path, action: str) -> LunarAlbedoError:
    if isinstance(typed_error(exc), DiskFullError):
        return DiskFullError(f"{path}: no space left on the device")
    texts = [str(e) for e in (exc, exc.__cause__, exc.__context__) if e is not None and "previous exception" not in str(e)]
    detail = "; ".join(dict.fromkeys(t.replace(str(path), "").strip(" :,") for t in texts if t)) or type(exc).__name__
    if action == "write":
        return OutputError(f"{path}: cannot write raster: {detail}")
    return InputError(f"{path}: cannot read raster pixels (truncated or corrupt file?): {detail}")


def check_output_dir(path: str | Path, what: str = "output folder") -> Path:
    """Refuse early (before any work) an output folder that cannot be created or written.

    :class:`OutputError` naming ``path`` when it, or its nearest existing parent, is a
    regular file or not writable.  Nothing is created here.
    """
    import os

    path = Path(path).absolute()
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: cannot use as {what}: it exists and is not a folder")
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{path}: cannot create the {what}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: cannot create or write the {what}: no write permission on {probe}")
    return path
