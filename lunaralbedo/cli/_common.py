"""Helpers shared by the CLI commands: error reporting and option types."""
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
