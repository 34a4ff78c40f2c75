"""Typed exceptions of lunaralbedo.

Every error raised on bad input derives from :class:`LunarAlbedoError`, names the
offending file (or settings key) and says what is wrong.  The CLI turns them into
a one-line message and a non-zero exit status.
"""
from __future__ import annotations


class LunarAlbedoError(Exception):
    """Base class of every error the package raises on purpose."""

    exit_code = 2


class SettingsError(LunarAlbedoError):
    """A settings file is unreadable, has an unknown key or an invalid value."""


class InputError(LunarAlbedoError):
    """An input file (raster, position list, cube, kernel) is missing or malformed."""


class DuplicateKeyError(InputError):
    """Two DRG files share the same 11-character lookup key."""


class MissingPositionError(InputError):
    """A DRG has no line in the Sun or spacecraft position file."""


class IsisError(InputError):
    """An ISIS3 cube or label cannot be read or lacks a required group/table."""


class SpiceError(InputError):
    """A kernel is missing, a time is not covered or a frame is unknown."""


class SolverError(LunarAlbedoError):
    """The solve cannot proceed (e.g. no image overlaps the simulation box)."""


class ResumeError(LunarAlbedoError):
    """A run cannot be resumed (the checkpoint belongs to other settings)."""


class OutputError(LunarAlbedoError):
    """An output path cannot be created or written (below a regular file, no permission)."""


class InfrastructureError(LunarAlbedoError):
    """The machinery failed, not the input: a worker lost, a cluster that cannot start, the disk full.

    Exit status 3.  The checkpoint is kept, so ``--resume`` can finish the run.
    """

    exit_code = 3


class WorkerLostError(InfrastructureError):
    """A Dask worker died (killed, out of memory) while running a task."""


class ClusterError(InfrastructureError):
    """A Dask cluster, scheduler or batch job could not be started or reached."""


class DiskFullError(InfrastructureError):
    """No space left on the device (or quota exceeded) while writing an output."""


class Interrupted(LunarAlbedoError):
    """The run was interrupted (Ctrl-C / SIGINT); exit status 130."""

    exit_code = 130


_DISK_FULL_ERRNOS = {28, 122}  # ENOSPC, EDQUOT
#: GDAL's and NumPy's words for a full disk (NumPy's short write, "N requested and M written", has no errno)
_DISK_FULL_TEXT = ("no space left", "free disk space", "disk quota", "requested and")
_WORKER_LOST = {"KilledWorker", "CommClosedError", "StreamClosedError"}
_FUTURE_CANCELLED = {"CancelledError", "FutureCancelledError"}


def _class_names(exc: BaseException) -> set[str]:
    return {c.__name__ for c in type(exc).__mro__}


def typed_error(exc: BaseException) -> LunarAlbedoError | None:
    """The typed error that stands for ``exc``, or None for an unexpected one (a bug).

    Maps without importing the libraries: GDAL/rasterio errors become :class:`InputError`
    (their message names the file), a full disk :class:`DiskFullError`, a lost Dask
    worker :class:`WorkerLostError`, Ctrl-C :class:`Interrupted`, any other ``OSError``
    with a file name a :class:`LunarAlbedoError` naming it.
    """
    if isinstance(exc, LunarAlbedoError):
        return exc
    if isinstance(exc, KeyboardInterrupt):
        return Interrupted("interrupted (Ctrl-C)")
    names = _class_names(exc)
    text = str(exc)
    if (isinstance(exc, OSError) and exc.errno in _DISK_FULL_ERRNOS) or any(t in text.lower() for t in _DISK_FULL_TEXT):
        where = getattr(exc, "filename", None)
        return DiskFullError(f"{where}: no space left on the device" if where else f"no space left on the device ({text})")
    if names & _WORKER_LOST:
        return WorkerLostError(f"a Dask worker was lost while running a task ({type(exc).__name__}: {text})")
    if names & _FUTURE_CANCELLED:
        return WorkerLostError(f"a task was cancelled by the Dask scheduler ({text or type(exc).__name__})")
    if type(exc).__module__.startswith("rasterio") or "RasterioIOError" in names or "CPLE_BaseError" in names:
        return InputError(f"raster read/write failed: {text}")
    if isinstance(exc, OSError) and exc.filename:
        return LunarAlbedoError(f"{exc.filename}: {exc.strerror or text}")
    return None
