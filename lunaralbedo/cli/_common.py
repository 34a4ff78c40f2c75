"""Helpers shared by the CLI commands: error reporting, exit codes and the options every command shares.

Exit codes (see docs/errors.md): 0 success, 2 bad input (incl. an output path that
cannot be created), 3 infrastructure (worker lost, cluster cannot start, disk full),
130 interrupted (Ctrl-C), 141 output pipe closed (``| head -1``; nothing printed),
1 an unexpected internal error (a bug: please report it).
Without the global ``--debug`` no traceback is printed, only ``error: <message>``.
"""
from __future__ import annotations

import functools
import math
import os
import sys
import traceback
from typing import Callable

import click

from ..errors import ClusterError, InputError, Interrupted, LunarAlbedoError, typed_error

INTERNAL_ERROR = 1
#: Exit status when the reader of our output went away (``| head -1``): 128 + SIGPIPE, as a shell tool killed by it.
BROKEN_PIPE = 141
#: Whether this command chose full-width vectors for itself (:func:`_vector_width`); its workers follow.
_WIDE_VECTORS = [False]


def cli_runtime(**given):
    """The :class:`~lunaralbedo.runtime.Runtime` of a command: its environment variables
    (:data:`lunaralbedo.runtime.VARIABLES`) and ``given`` fields.  This process and its workers are tuned
    (:mod:`lunaralbedo.parallel.workers`) unless the user set malloc or NumPy variables of their own."""
    from ..parallel.workers import MALLOC_ENV, NUMPY_ENV
    from ..runtime import Runtime

    users = any(k in os.environ for k in (*MALLOC_ENV, *NUMPY_ENV))
    return Runtime.from_environ(os.environ, tune_workers=not users, tune_process=not users,
                                wide_vectors=_WIDE_VECTORS[0], **given)


def debug_enabled() -> bool:
    """True when the global ``--debug`` option was given."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx and (ctx.find_root().obj or {}).get("debug"))


def _has_resume() -> bool:
    """True when the running command has a ``--resume`` option (only then is a checkpoint kept)."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx and any(p.name == "resume" for p in ctx.command.params))


def _hint(exc: LunarAlbedoError) -> str:
    if isinstance(exc, ClusterError):  # the cluster did not start: no work was done
        return ""
    if (exc.exit_code == 3 or isinstance(exc, Interrupted)) and _has_resume():
        return " (the checkpoint is kept: rerun the same command with --resume)"
    return ""


def _vector_width() -> None:
    """The command line's process-wide choice, made as a command starts (not for ``--help``) and before it
    imports numba (the library makes none): full-width vectors on AVX-512 CPUs unless
    ``LUNARALBEDO_VECTOR_BITS=256`` or numba's own variables say otherwise (:mod:`lunaralbedo.simd`)."""
    from .. import simd

    try:
        _WIDE_VECTORS[0] = simd.apply(os.environ) is not None
    except ValueError as exc:  # a bad LUNARALBEDO_VECTOR_BITS: say so, and leave numba's defaults
        click.echo(f"warning: {exc}", err=True)


def _quiet_broken_pipe() -> None:
    """The reader of stdout went away: point stdout at /dev/null (so that the interpreter's last flush does
    not complain) and end with :data:`BROKEN_PIPE`, saying nothing."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real stdout (tests): nothing to flush
        pass
    sys.exit(BROKEN_PIPE)


def reports_errors(func: Callable) -> Callable:
    """Turn any failure into one line ``error: <message>`` on stderr and its exit status.

    Typed errors keep their ``exit_code``; library errors are mapped by
    :func:`lunaralbedo.errors.typed_error`; anything else is an internal error
    (exit 1).  With ``--debug`` the traceback is printed as well.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        _vector_width()
        try:
            return func(*args, **kwargs)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except BrokenPipeError:
            _quiet_broken_pipe()
        except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - the one place that reports failures
            typed = typed_error(exc)
            if debug_enabled():
                traceback.print_exception(exc, file=sys.stderr)
            if typed is None:
                click.echo(f"error: internal error ({type(exc).__name__}: {exc}); rerun with --debug for the "
                           "traceback and please report it", err=True)
                sys.exit(INTERNAL_ERROR)
            click.echo(f"error: {typed}{_hint(typed)}", err=True)
            sys.exit(typed.exit_code)

    return wrapper


def check_number(name: str, value, low=None, high=None, low_open: bool = False, integer: bool = False) -> None:
    """Raise :class:`InputError` (exit 2, one line naming option ``name``) unless ``value`` is None or a
    finite number in ``[low, high]`` (``(low, high]`` with ``low_open``); called before anything is written."""
    if value is None:
        return
    if not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value}")
    if integer and value != int(value):
        raise InputError(f"{name} must be a whole number, got {value}")
    if low is not None and (value <= low if low_open else value < low):
        raise InputError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {value:g}")
    if high is not None and value > high:
        raise InputError(f"{name} must be <= {high:g}, got {value:g}")


#: Modules whose numba kernels the solver's tile tasks compile (``cache=True``) on the first run after installing.
SOLVER_KERNELS = ("lunaralbedo.engine.kernels", "lunaralbedo.engine.finalise_kernels", "lunaralbedo.engine.runs")
#: ... and ingest's orthoprojection.
INGEST_KERNELS = ("lunaralbedo.ingest.sampling", "lunaralbedo.ingest.approx")


def _jit_cached(module: str) -> bool:
    """True when numba's cache holds compiled kernels of ``module`` (an index ``<stem>.*.nbi`` beside the file,
    or in ``NUMBA_CACHE_DIR``)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None:
        return True
    src = Path(spec.origin)
    places = [src.parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        places.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    return any(any(p.rglob(f"{src.stem}.*.nbi")) for p in places if p.is_dir())


def announce_compiling(modules: tuple[str, ...], tty: bool | None = None) -> bool:
    """Say once, on stderr, that this first run compiles the numerical kernels (not a slow run); True if it did.

    Only on a terminal (``tty`` None: whether stderr is one): scripts and pipes keep their one-line errors.
    """
    if not (sys.stderr.isatty() if tty is None else tty) or all(_jit_cached(m) for m in modules):
        return False
    click.echo("note: first run after installing: compiling the numerical kernels (numba), about a minute "
               "on a busy machine; later runs reuse them", err=True)
    return True


def parallel_options(default: str) -> Callable:
    """``--workers N`` and ``--scheduler ADDRESS``, with the same meaning in every command.

    ``default`` says in the help what ``--workers`` defaults to for this command.
    See :func:`lunaralbedo.parallel.make_executor`.
    """

    def decorate(func: Callable) -> Callable:
        func = click.option("--scheduler", default=None, metavar="ADDRESS",
                            help="Run on the workers of an existing dask.distributed scheduler (tcp://host:port).")(func)
        return click.option("--workers", type=click.IntRange(min=1), default=None,
                            help=f"Workers on this machine (1 = in-process, serial; default: {default}).")(func)

    return decorate


def pyramid_options(func: Callable) -> Callable:
    """``--levels``, ``--stretch``, ``--range`` and ``--tile-size``: the tile pyramid and its one 8-bit
    albedo stretch, shared by ``export-kml`` and ``export-web`` (see :func:`pyramid_kwargs`)."""
    for option in reversed((
        click.option("--levels", type=int, default=None, help="Pyramid levels (default: as many as the data needs)."),
        click.option("--stretch", "stretch", default=None, metavar="pLO,pHI", help="Albedo percentile stretch, e.g. p2,p98 (default)."),
        click.option("--range", "value_range", default=None, metavar="LO,HI", help="Fixed albedo stretch: LO -> 0 (black), HI -> 255 (white)."),
        click.option("--tile-size", type=int, default=256, show_default=True, help="PNG tile size in pixels."),
    )):
        func = option(func)
    return func


def pyramid_kwargs(levels, stretch, value_range, tile_size) -> dict:
    """The keyword arguments of :func:`lunaralbedo.export.export_kml` / ``export_web`` from :func:`pyramid_options`."""
    from ..export.stretch import parse_pair

    if stretch is not None and value_range is not None:
        raise InputError("give either --stretch or --range, not both")
    return {
        "levels": levels,
        "stretch": parse_pair(stretch, "--stretch") if stretch is not None else (2.0, 98.0),
        "value_range": parse_pair(value_range, "--range") if value_range is not None else None,
        "tile_size": tile_size,
    }

