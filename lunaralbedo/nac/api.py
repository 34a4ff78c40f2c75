"""File-level entry points of the NAC tools (callable from a notebook; the CLI is a thin layer over them)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .images import read_image
from .jitreg import register
from .jitreg_files import write_jitreg


def jitreg(le: str | Path, re: str | Path, prefix: str | Path, window: int = 32, step: int = 8, search: int = 10,
           crop_width: int = 200, output_log: str | Path | None = None) -> dict:
    """Register RE onto LE (same ideal-camera grid) and write the ``jitreg`` outputs; return the summary dict."""
    le, re = Path(le), Path(re)
    result = register(read_image(le), read_image(re), window=window, step=step, search=search, crop_width=crop_width)
    return write_jitreg(prefix, result, le, re, Path(output_log) if output_log else None)


def nac_pairs(cubes: Sequence[Path]) -> tuple[list[tuple[Path, Path]], list[Path]]:
    """LE/RE pairs of one observation among ``cubes`` (``InstrumentId`` NACL/NACR, same ``StartTime``) and the rest."""
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
    """``ingest --dem-align/--nac-mosaic``: aligned DEMs and mosaicked pairs in ``workdir/nac``; returns
    ``(cubes, dems, messages)`` to ingest instead of the given ones."""
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
