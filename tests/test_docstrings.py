"""The public API a scientist calls from a notebook carries numpydoc docstrings that match its signatures.

``numpydoc.validate`` reads each docstring and compares its Parameters with the function's
signature, so adding a parameter without documenting it (or renaming one and leaving the old
name in the docstring) fails here.  ``lunaralbedo.engine.solve.solve`` belongs in the list
once its docstring is numpydoc too.
"""
from __future__ import annotations

import re
import textwrap

import pytest
from numpydoc.validate import validate

PUBLIC_API = (
    "lunaralbedo.engine.solve.solve",
    "lunaralbedo.ingest.run.ingest",
    "lunaralbedo.ingest.positions.compute_positions",
    "lunaralbedo.export.api.export_kml",
    "lunaralbedo.web.api.export_web",
    "lunaralbedo.backplanes.run.camera_geometry",
    "lunaralbedo.backplanes.run.write_backplanes",
    "lunaralbedo.phocorr.run.correct",
    "lunaralbedo.phocorr.run.read_backplane",
    "lunaralbedo.nac.api.jitreg",
    "lunaralbedo.nac.api.prepare_ingest",
    "lunaralbedo.nac.api.nac_pairs",
    "lunaralbedo.nac.mosaic.nac_mosaic",
    "lunaralbedo.nac.align_files.align_files",
    "lunaralbedo.nac.align.icp",
    "lunaralbedo.response.aligned.recover_response",
    "lunaralbedo.response.fit.fit_response",
    "lunaralbedo.simulate.strip.render_scene",
    "lunaralbedo.simulate.render_mission",
    "lunaralbedo.simulate.truth.score",
    "lunaralbedo.runtime.Runtime",
    "lunaralbedo.runtime.Runtime.but",
    "lunaralbedo.runtime.Runtime.from_environ",
)

#: The checks enforced: a docstring exists (GL08); every parameter documented (PR01), none unknown (PR02),
#: each with a description (PR07); a Returns section where something is returned (RT01) with a description
#: (RT03); a one-line summary that starts on the first line (SS01, SS03 full stop, SS06 one line).
CHECKS = {"GL08", "PR01", "PR02", "PR07", "RT01", "RT03", "SS01", "SS03", "SS06"}


def _errors(name: str) -> list[tuple[str, str]]:
    return [(code, msg) for code, msg in validate(name)["errors"] if code in CHECKS]


@pytest.mark.parametrize("name", PUBLIC_API)
def test_public_function_has_a_numpydoc_docstring(name):
    assert _errors(name) == [], f"{name}: docstring does not match numpydoc"


@pytest.mark.parametrize("name", PUBLIC_API)
def test_docstring_cites_sources_by_name(name):
    doc = validate(name)["docstring"]
    assert not re.search(r"\bseed \d{3}\b", doc), f"{name}: cite the published source by name, not 'seed NNN'"


def test_the_check_fails_on_an_undocumented_parameter(tmp_path, monkeypatch):
    """The test above can fail: a new parameter left out of a docstring, and a stale one, are caught."""
    (tmp_path / "docstring_probe.py").write_text(textwrap.dedent('''
        def fn(path, workers=1):
            """Read a file.

            Parameters
            ----------
            path : str
                The file.
            threads : int
                Gone from the signature.

            Returns
            -------
            int
                Bytes read.
            """
            return 0
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    codes = {code for code, _ in _errors("docstring_probe.fn")}
    assert {"PR01", "PR02"} <= codes


def test_no_source_file_has_an_invalid_escape():
    r"""A docstring with LaTeX in a plain string loses characters: ``"\top"`` is a tab and ``op``.  Every module
    of the package, the tests, tools and benchmarks compiles without an escape warning (raw strings, ``r\"\"\"``)."""
    import warnings
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    bad = []
    for path in sorted(p for d in ("lunaralbedo", "tests", "tools", "benchmarks") for p in (root / d).rglob("*.py")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                compile(path.read_text(), str(path), "exec")
            except (SyntaxError, SyntaxWarning, DeprecationWarning) as e:
                bad.append(f"{path.relative_to(root)}: {e}")
    assert not bad, bad
