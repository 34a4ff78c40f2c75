"""Helpers shared by the CLI commands: error reporting and the options every command shares."""
from __future__ import annotations

import functools
import sys
from typing import Callable

import click

from ..errors import LunarAlbedoError


def reports_errors(func: Callable) -> Callable:
    """Turn a :class:`LunarAlbedoError` into ``error: <message>`` on stderr and exit status 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except LunarAlbedoError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(exc.exit_code)

    return wrapper


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
