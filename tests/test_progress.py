"""Progress that moves: the solver's row bar advances a block of rows at a time in every pass, and the
first run's kernel compilation is announced once (not reported as a slow run)."""
from __future__ import annotations

import lunaralbedo
from lunaralbedo.simulate import SceneSpec, render_scene


class Recorder:
    """Stands in for the row bar (:data:`lunaralbedo.parallel.progress.ROWS`): what each pass was started with and the rows it was advanced by."""

    def __init__(self):
        self.passes: list[tuple[str, int, list[int]]] = []

    def start(self, desc, total):
        self.passes.append((desc, total, []))

    def advance(self, rows):
        self.passes[-1][2].append(rows)

    def stop(self):
        pass


def test_row_bar_moves_block_by_block(tmp_path, monkeypatch):
    render_scene(tmp_path / "scene", SceneSpec(n_images=4, overlap=0.8, image_px=60, tile_size=0.25, max_num_iter=3, seed=5))
    rec = Recorder()
    import lunaralbedo.engine.prepare as prepare
    import lunaralbedo.engine.solve as solve
    import lunaralbedo.engine.tilework as tilework

    import lunaralbedo.engine.robust as robust

    for mod in (prepare, solve, tilework, robust):
        monkeypatch.setattr(mod, "ROWS", rec)
    # blocks of 7 rows, as a tile over the memory budget is done
    res = lunaralbedo.solve(tmp_path / "scene" / "settings.txt", out=tmp_path / "out", workers=1, progress=True,
                            plots=False, tolerance=0, runtime=lunaralbedo.Runtime(block_rows=7))
    names = [p[0] for p in rec.passes]
    assert names[0] == "prepare" and names[-1] == "write tiles" and names.count("iteration 1") == 1
    reweights = [n for n in names if n.startswith("outliers")]  # the robust loss's passes (engine/robust.py; three images meet)
    assert len(reweights) == res.report["outliers"]["reweight_passes"] >= 1
    assert len(names) == 2 + res.iterations + len(reweights)
    for desc, total, steps in rec.passes:
        assert sum(steps) == total, desc  # every row of every tile, once per pass
        assert len(steps) >= total // 7 and max(steps) <= 7, desc  # a step per block, not per tile


def test_first_run_compilation_is_announced(tmp_path, monkeypatch, capsys):
    from lunaralbedo.cli._common import announce_compiling

    (tmp_path / "jitmod.py").write_text("x = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert not announce_compiling(("jitmod",), tty=False)  # scripts and pipes: nothing
    assert capsys.readouterr().err == ""
    announce_compiling(("jitmod",), tty=True)
    assert "compiling the numerical kernels" in capsys.readouterr().err
    (tmp_path / "__pycache__").mkdir()
    (tmp_path / "__pycache__" / "jitmod.kernel-1.py311.nbi").write_bytes(b"")  # numba's cache index
    announce_compiling(("jitmod",), tty=True)
    assert capsys.readouterr().err == ""
