"""Command-line interface: a thin click layer over the Python API.

Each command lives in its own module of this package and exposes a click command
named ``command``; modules are discovered here, so adding a file ``cli/<name>.py`` adds
the command ``<name>`` (underscores become hyphens: ``export_kml.py`` is ``export-kml``).
A command's module is imported only when the command is looked up (its run, its ``--help``,
the list of ``lunaralbedo --help``), and it imports its heavy dependencies (numba, dask,
rasterio, ...) inside the command function: ``lunaralbedo --help`` loads none of them.
"""
from __future__ import annotations

import importlib
import pkgutil

import click

from .. import __version__


def _command_modules() -> dict[str, str]:
    """Command name -> module name, for every public module of this package (none is imported)."""
    names = (m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))
    return {name.replace("_", "-"): name for name in sorted(names)}


class _LazyGroup(click.Group):
    """A click group that imports a command's module when the command is looked up."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *_command_modules()})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module = _command_modules().get(cmd_name)
        if module is None:
            return super().get_command(ctx, cmd_name)
        cmd = getattr(importlib.import_module(f"{__name__}.{module}"), "command", None)
        if not isinstance(cmd, click.Command) or cmd.name != cmd_name:
            raise RuntimeError(f"lunaralbedo.cli.{module} must define a click command named {cmd_name!r} as `command`")
        return cmd


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lunaralbedo")
@click.option("--debug", is_flag=True, help="Print the Python traceback of a failure (for bug reports).")
@click.pass_context
def main(ctx: click.Context, debug: bool) -> None:
    """lunaralbedo: calibrated albedo maps of the Moon from orbital images.

    Typical run: ``ingest`` (cubes -> DRGs + positions), ``solve`` (albedo),
    ``export-kml`` (Google Earth / GIS products).  Exit status: 0 done, 2 bad input,
    3 infrastructure failure (worker lost, disk full), 130 interrupted (docs/errors.md).
    """
    ctx.obj = {**(ctx.obj or {}), "debug": debug}
