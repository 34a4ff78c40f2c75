"""File-level entry points of the NAC tools (callable from a notebook; the CLI is a thin layer over them)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .images import read_image
from .jitreg import register
from .jitreg_files import write_jitreg


def jitreg(le: str | Path, re: str | Path, prefix: str | Path, window: int = 32, step: int = 8, search: int = 10,
           crop_width: int = 200, output_log: str | Path | None = None) -> dict:
    """Measure the offset and jitter between the LE and RE images of an LRO NAC pair.

    ASP's ``lronacjitreg`` (the ASP LRO-NAC notes; ISIS ``hijitreg`` for HiRISE): the two
    CCD images, resampled onto one ideal-camera grid, are matched in windows of ``window``
    lines every ``step`` lines over their overlap columns, with a global integer offset
    from phase correlation and a sub-pixel one per window from OpenCV's
    enhanced-correlation-coefficient maximisation (Evangelidis & Psarakis 2008); windows
    with a correlation below 0.5 or an offset more than 2 px from the median are
    rejected (see :mod:`lunaralbedo.nac.jitreg`).  Writes ``PREFIX.json`` (the summary),
    ``PREFIX-lines.csv`` (one row per window), ``PREFIX-jitter.png`` and, with
    ``output_log``, ``lronacjitreg``'s log format.

    Parameters
    ----------
    le, re : str or Path
        The LE and RE images on one grid, same size (GeoTIFF or ISIS cube, band 1; NaN,
        no-data or ISIS special pixels outside each CCD).
    prefix : str or Path
        Prefix of the output files.
    window : int, default 32
        Height of a matching window, lines (at least 4).
    step : int, default 8
        Lines between window centres.
    search : int, default 10
        Largest offset searched, pixels.
    crop_width : int, default 200
        Widest band of overlap columns used, pixels.
    output_log : str or Path, optional
        Also write an ASP ``lronacjitreg``-style log here.

    Returns
    -------
    dict
        The summary (also ``PREFIX.json``): ``left``, ``right`` (paths); ``sample_offset``
        and ``line_offset`` (mean over good windows, pixels, with the convention that the
        feature at RE pixel ``(x, y)`` lies at LE pixel ``(x + sample_offset, y +
        line_offset)`` -- the opposite sign of ASP's); their ``_stderr`` (over the
        effective number of independent windows) and ``_std``; ``good_matches``,
        ``windows``; ``overlap_columns`` (``[start, stop)``), ``window_lines``,
        ``step_lines``, ``convention`` (that sentence) and ``integer_offset`` (the
        phase-correlation ``[sample, line]``).

    Raises
    ------
    InputError
        Exit 2: an image missing or unreadable, images of different sizes, an invalid
        ``window``/``step``/``search``, or an overlap too narrow or too short to match.
    """
    le, re = Path(le), Path(re)
    result = register(read_image(le), read_image(re), window=window, step=step, search=search, crop_width=crop_width)
    return write_jitreg(prefix, result, le, re, Path(output_log) if output_log else None)


def nac_pairs(cubes: Sequence[Path]) -> tuple[list[tuple[Path, Path]], list[Path]]:
    """Find the LE/RE pairs of one LRO NAC observation among cubes.

    Two cubes form a pair when their labels' ``Instrument`` groups have ``InstrumentId``
    ``NACL`` and ``NACR`` with the same ``SpacecraftName`` and ``StartTime``.

    Parameters
    ----------
    cubes : sequence of str or Path
        ISIS3 cubes or labels.

    Returns
    -------
    pairs : list of tuple of Path
        ``(le, re)`` per observation that has both sides, in the order first seen.
    rest : list of Path
        The other cubes (not NAC, or a side without its partner), in the given order.

    Raises
    ------
    IsisError
        Exit 2: a label cannot be read or has no ``Instrument`` group.
    """
    from ..isis.labels import read_label

    sides: dict[tuple[str, str], dict[str, Path]] = {}
    for c in map(Path, cubes):
        inst = read_label(c).instrument
        iid = str(inst.get("InstrumentId", "")).upper()
        if iid in ("NACL", "NACR"):
            sides.setdefault((str(inst.get("SpacecraftName", "")), str(inst.get("StartTime", ""))), {})[iid[-1]] = c
    pairs = [(s["L"], s["R"]) for s in sides.values() if len(s) == 2]
    paired = {p for pr in pairs for p in pr}
    return pairs, [Path(c) for c in cubes if Path(c) not in paired]


def prepare_ingest(cubes: Sequence[Path], dems: Sequence[Path], workdir: Path, dem_align: Path | None = None,
                   nac_mosaic: bool = False, kernels: Sequence[Path] = (), isisdata=None, dem_mode: str = "auto",
                   max_displacement: float = float("inf")) -> tuple[list[Path], list[Path], list[str]]:
    """Prepare the NAC inputs of ``ingest``: align the DEMs and mosaic the LE/RE pairs.

    The ASP LRO-NAC notes' chain before orthoprojection (``ingest --dem-align`` /
    ``--nac-mosaic``).  With ``dem_align``, each DEM is aligned to the reference by
    :func:`lunaralbedo.nac.align_files.align_files` (ASP ``pc_align``), writing
    ``workdir/nac/<DEM stem>-*`` and using ``<DEM stem>-trans_dem.tif`` (heights, metres)
    instead.  With ``nac_mosaic``, each LE/RE pair (:func:`nac_pairs`) is mosaicked by
    :func:`lunaralbedo.nac.mosaic.nac_mosaic` (ASP ``lronac2mosaic.py``) onto the ideal
    camera at the first DEM's mean height, into ``workdir/nac/<observation>.cub``.

    Parameters
    ----------
    cubes : sequence of Path
        The cubes given to ``ingest``.
    dems : sequence of Path
        The DEMs given to ``ingest``.
    workdir : Path
        The ``ingest`` work folder; outputs go to ``workdir/nac``.
    dem_align : Path, optional
        Reference to align the DEMs to: a CSV of ``lon, lat, radius`` (degrees, km, as
        LOLA RDR exports) or a DEM.  None: the DEMs are used as given.
    nac_mosaic : bool, default False
        Mosaic each LE/RE pair into one ideal-camera cube.
    kernels : sequence of Path, optional
        Extra SPICE kernels (already expanded) for the mosaic's cameras.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` kernel paths.
    dem_mode : {"auto", "radius", "height"}, default "auto"
        How to read the DEM values (radius in metres, or height above 1737.4 km).
    max_displacement : float, default inf
        Alignment: reference points farther than this from the DEM at the start are
        dropped, metres.

    Returns
    -------
    cubes : list of Path
        The cubes to ingest: the mosaics, then the cubes not paired (or the given ones).
    dems : list of Path
        The DEMs to ingest: the aligned ones (holding heights), or the given ones.
    messages : list of str
        One line per DEM aligned (its shift in metres, median error before and after) and
        per pair mosaicked (the RE offset in pixels), for the user.

    Raises
    ------
    InputError
        Exit 2: an unreadable DEM or reference, a reference that does not overlap the DEM
        or too few points to fix a rigid transform (nothing written then).
    IsisError
        Exit 2: a cube whose label cannot be read.
    SpiceError
        Exit 2: a missing kernel for the mosaic's cameras.
    """
    import numpy as np

    from ..ingest.dem import DemMosaic, load_dems
    from .align_files import align_files
    from .mosaic import nac_mosaic as mosaic_pair

    notes: list[str] = []
    dems, cubes = [Path(d) for d in dems], [Path(c) for c in cubes]
    if dem_align is not None:
        aligned = []
        for src in load_dems(dems, dem_mode):
            r = align_files(src.path, dem_align, workdir / "nac" / src.path.stem, max_displacement, dem_mode=dem_mode)
            aligned.append(workdir / "nac" / f"{src.path.stem}-trans_dem.tif")
            t = r["translation_at_dem_centre"]
            notes.append(f"DEM {src.path} aligned to {dem_align}: moved {t['horizontal']:.2f} m horizontally, "
                         f"{-t['down']:+.2f} m up; median error {r['before']['median']:.2f} -> {r['after']['median']:.2f} m")
        dems = aligned
    if nac_mosaic:
        pairs, rest = nac_pairs(cubes)
        h = float(np.nanmean(DemMosaic(load_dems(dems, "height" if dem_align else dem_mode)).sources[0].heights))
        out = []
        for le, re in pairs:
            m = mosaic_pair(le, re, workdir / "nac" / f"{le.stem.split('.')[0].rstrip('LER_')}.cub", None, kernels,
                            isisdata, height_m=h)
            notes.append(f"{le.name} + {re.name} -> {m.path} (RE offset {m.sample_offset:+.3f}, {m.line_offset:+.3f} px)")
            out.append(m.path)
        cubes = out + rest
    return cubes, dems, notes
