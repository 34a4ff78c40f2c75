"""Full-width vectors on AVX-512 CPUs (lunaralbedo.simd): when numba is told, what it compiles, and that
no result changes with the width."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from lunaralbedo import simd

HOST = "+sse2,+avx2,+avx512f,-amx-tile"


def _host(called):
    def features():
        called.append(True)
        return HOST
    return features


def test_wide_features_only_where_the_user_left_numba_alone_and_the_cpu_has_avx512():
    called = []
    assert simd.wide_features({}, _host(called)) == HOST + ",-prefer-256-bit"
    assert simd.wide_features({simd.SWITCH: "512"}, _host(called)) == HOST + ",-prefer-256-bit"
    assert called == [True, True]
    called.clear()
    for env in ({simd.SWITCH: "256"}, {"NUMBA_CPU_FEATURES": "+avx2"}, {"NUMBA_CPU_NAME": "generic"},
                {"NUMBA_CPU_FEATURES": ""}):  # numba compiles for no features at all then: the user's choice
        assert simd.wide_features(env, _host(called)) is None, env
    assert called == []  # the host is not even asked
    assert simd.wide_features({}, lambda: "+sse2,+avx2,-avx512f") is None  # no AVX-512F: LLVM's choice stands
    assert simd.wide_features({}, lambda: "+sse2,+avx512fp16,-avx512f") is None  # another avx512 feature is not F
    assert simd.wide_features({}, lambda: "") is None  # LLVM could not tell the host's features
    with pytest.raises(ValueError, match="LUNARALBEDO_VECTOR_BITS='128'"):
        simd.wide_features({simd.SWITCH: "128"}, _host(called))


def test_apply_does_nothing_once_numba_has_made_its_target():
    import lunaralbedo.engine.kernels  # noqa: F401  (numba's target is made by now)

    env = {}
    assert simd.apply(env) is None and env == {}


needs_avx512 = pytest.mark.skipif("+avx512f" not in simd._host_features().split(","), reason="the CPU has no AVX-512F: numba keeps its own vector width")


_FEATURES = """
import os, sys
before = dict(os.environ)
import lunaralbedo
{what}
from lunaralbedo.engine import kernels  # numba's target is made by now
from numba.core import config
print(str(config.CPU_FEATURES).endswith("-prefer-256-bit"), dict(os.environ) == before)
"""


def _features_after(what: str) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k not in (simd.SWITCH, *simd.NUMBA_VARIABLES)}
    res = subprocess.run([sys.executable, "-c", _FEATURES.format(what=what)], env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout.split()


def test_importing_the_package_changes_nothing_process_wide():
    """The library leaves numba's configuration and the environment as they were: the vector width is the
    command line's choice (or the caller's, with simd.apply)."""
    assert _features_after("import lunaralbedo.cli") == ["False", "True"]  # the CLI's import alone neither


@needs_avx512
def test_the_command_line_asks_numba_for_full_width_vectors_in_its_own_process_only():
    """A command, as it starts (``cli._common.reports_errors`` calls this before the command's own imports), told
    numba, in this process only (nothing in the environment a batch job could carry to a node with another
    CPU).  What LLVM then emits is its own business: no assertion on it."""
    assert _features_after("from lunaralbedo.cli._common import _vector_width; _vector_width()") == ["True", "True"]


_CHILD = """
import os, sys
import numba.core.config as config
from lunaralbedo import simd
simd.apply(os.environ)  # as the command line does
from lunaralbedo.engine.solve import solve

print(str(config.CPU_FEATURES).endswith("-prefer-256-bit"))
solve(sys.argv[1], out=sys.argv[2], workers=1, plots=False)
"""


@needs_avx512
def test_a_solve_gives_the_same_bytes_at_either_vector_width(tmp_path):
    """The same scene solved in two processes, one with full-width vectors and one with
    LUNARALBEDO_VECTOR_BITS=256: every tile and table the same bytes, Q and the parameters the
    same float64 (each kernel compiled at both widths: the prepare step's geometry and shadows,
    the iterations, finalise)."""
    from lunaralbedo.simulate import SceneSpec, render_scene

    from test_engine import same_results

    render_scene(tmp_path / "scene", SceneSpec(n_images=6, image_px=90, tile_size=0.25, max_num_iter=4, seed=21))
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", simd.SWITCH)}
    outs = {}
    for bits in ("512", "256"):
        outs[bits] = tmp_path / f"out{bits}"
        res = subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path / "scene" / "settings.txt"), str(outs[bits])],
                             env={**base, simd.SWITCH: bits}, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr[-2000:]
        wide = res.stdout.split()[0]
        assert wide == str(bits == "512")  # the features each process compiled for
    # No assertion on how LLVM vectorised anything: whether a fast-math sum differs between the two widths
    # depends on the compiler's choices on the machine at hand (on some CPUs both give the same bits).  The
    # two processes did compile for different features (``wide`` above); their results must be equal.
    same_results(outs["512"], outs["256"])
    reports = [json.loads((outs[b] / "report.json").read_text()) for b in ("512", "256")]
    for key in ("cost_q", "parameters"):  # float64 in full: the global sums' lanes at either width
        assert reports[0][key] == reports[1][key], key


_WORKERS = """
import sys
from lunaralbedo.parallel.executor import make_executor
from lunaralbedo.runtime import Runtime

def features():
    from lunaralbedo.engine import kernels  # noqa: F401  (a kernel module: numba's target is made)
    from numba.core import config
    return str(config.CPU_FEATURES).endswith("-prefer-256-bit")

ex = make_executor(workers=2, runtime=Runtime(wide_vectors=sys.argv[1] == "1"))
try:
    print(*sorted(ex.client.run(features).values()))
finally:
    ex.close()
"""


@needs_avx512
@pytest.mark.parametrize("wide", [True, False])
def test_local_workers_compile_for_the_vector_width_of_the_run(wide):
    """With ``Runtime(wide_vectors=True)`` (the command line's choice where it took full-width vectors for
    itself) both local workers compile for the same features as the command's process, so a run uses one
    width and one set of cached kernels; without it they keep numba's own choice."""
    env = {k: v for k, v in os.environ.items() if k not in (simd.SWITCH, *simd.NUMBA_VARIABLES)}
    res = subprocess.run([sys.executable, "-c", _WORKERS, "1" if wide else "0"], env=env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == [str(wide)] * 2
