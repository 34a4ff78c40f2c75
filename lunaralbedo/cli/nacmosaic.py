"""``lunaralbedo nacmosaic``: LE + RE cubes -> one ideal line-scan camera cube (ISIS noproj + handmos, as in the ASP LRO-NAC notes)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("nacmosaic")
@click.argument("le", type=click.Path(path_type=Path))
@click.argument("re", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out", required=True, type=click.Path(path_type=Path), help="Mosaic cube to write (.cub).")
@click.option("--offset", type=click.Path(path_type=Path), default=None,
              help="jitreg PREFIX.json to apply; without it the offset is measured (OUT-jitreg.* written).")
@click.option("--kernels", multiple=True, type=click.Path(path_type=Path), help="Extra kernel file/folder (repeatable).")
@click.option("--isisdata", type=click.Path(path_type=Path), default=None, envvar="ISISDATA",
              help="ISIS data area for $mission paths (default: $ISISDATA).")
@click.option("--height", "height_m", type=float, default=0.0, show_default=True,
              help="Height (m above 1737.4 km) of the sphere the ideal rays meet (use the mean DEM height).")
@click.option("--ideal", type=click.Choice(["auto", "noproj", "computed"]), default="auto", show_default=True,
              help="Ideal camera: the noproj numbers of the ASP LRO-NAC notes for LRO NAC (auto: when the LE is one), or computed "
                   "half-way between the LE/RE boresights from the camera models.")
@click.option("--block-lines", type=click.IntRange(min=1), default=256, show_default=True,
              help="Ideal lines resampled at a time (memory: about 80 bytes x samples per line; same output).")
@reports_errors
def command(le, re, out, offset, kernels, isisdata, height_m, ideal, block_lines):
    """Resample LE and RE into one ideal camera (LE as the match), register and mosaic them."""
    from ..nac.mosaic import nac_mosaic
    from ..spice.kernels import expand_kernel_args

    r = nac_mosaic(le, re, out, offset, expand_kernel_args(kernels), isisdata, height_m=height_m, ideal=ideal,
                   block_lines=block_lines)
    how = "measured by jitreg" if r.measured else "given"
    click.echo(f"{r.path}: {r.shape[0]} lines x {r.shape[1]} samples (ideal camera TransX0 {r.spec.x0:.4f} mm, "
               f"TransY0 {r.spec.y0:.4f} mm, {r.ideal_source}); RE offset {r.sample_offset:+.3f}, {r.line_offset:+.3f} px ({how}); "
               f"overlap columns {r.overlap[0]}..{r.overlap[1]}")
