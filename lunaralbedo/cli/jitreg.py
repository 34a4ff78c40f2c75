"""``lunaralbedo jitreg``: LE/RE offset and jitter series (ASP ``lronacjitreg``, the ASP LRO-NAC notes)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("jitreg")
@click.argument("le", type=click.Path(path_type=Path))
@click.argument("re", type=click.Path(path_type=Path))
@click.option("-o", "--output-prefix", "prefix", required=True, type=click.Path(path_type=Path),
              help="Writes PREFIX.json, PREFIX-lines.csv and PREFIX-jitter.png.")
@click.option("--window", type=int, default=32, show_default=True, help="Correlation window height (lines).")
@click.option("--step", type=int, default=8, show_default=True, help="Lines between window centres.")
@click.option("--search", type=int, default=10, show_default=True, help="Largest offset searched (pixels).")
@click.option("--crop-width", type=int, default=200, show_default=True, help="Widest overlap used (columns).")
@click.option("--output-log", type=click.Path(path_type=Path), default=None,
              help="Also write ASP lronacjitreg's per-row log (ASP sign convention).")
@reports_errors
def command(le, re, prefix, window, step, search, crop_width, output_log):
    """Offset of RE relative to LE on one ideal-camera grid, per window of lines.

    Convention: the feature at RE pixel (x, y) lies at LE pixel
    (x + sample_offset, y + line_offset).
    """
    from ..nac.api import jitreg

    s = jitreg(le, re, prefix, window, step, search, crop_width, output_log)
    click.echo(f"sample_offset {s['sample_offset']:+.4f} +- {s['sample_offset_stderr']:.4f} px, "
               f"line_offset {s['line_offset']:+.4f} +- {s['line_offset_stderr']:.4f} px "
               f"({s['good_matches']} of {s['windows']} windows, columns {s['overlap_columns']})")
