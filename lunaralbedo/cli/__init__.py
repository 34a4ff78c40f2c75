"""Command-line interface: a thin click layer over the Python API.

Each command lives in its own module of this package and exposes a click command
named ``command``; modules are discovered here, so adding a command is adding a file.
"""
from __future__ import annotations

import importlib
import pkgutil

import click

from .. import __version__


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
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


for _mod in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    _cmd = getattr(importlib.import_module(f"{__name__}.{_mod}"), "command", None)
    if isinstance(_cmd, click.Command):
        main.add_command(_cmd)
