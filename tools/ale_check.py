#!/usr/bin/env python3
"""Print the docs/ingest.md tables: our Kaguya MI/TC, Clementine UVVIS and Chandrayaan-2 TMC-2 cameras vs ale's ISDs,
and both against JAXA's corner coordinates in the Kaguya labels (tests/test_label_corners.py).

Uses the test data of tests/data/ale, ../shared/realdata (generic kernels, Kaguya TC label and kernels)
and the CSM-style ISD projection of tests/ale_isd.py (independent of lunaralbedo's camera code).
"""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))


def main() -> int:
    import conftest
    import test_lunar_cameras as t

    realdata = conftest.SHARED / "realdata"
    generic = realdata / "kernels" / "generic"
    for name in ("kaguya_mi", "kaguya_tc", "clementine_uvvis", "chandrayaan2_tmc2"):
        raw = t._compare(realdata, generic, name, isis_conventions=False)
        isis = t._compare(realdata, generic, name, isis_conventions=True)
        print(f"\n{name}\n\n| pixel (sample, line) | ours - ale (samples, lines) | ours - ISD read as ISIS does |\n| --- | --- | --- |")
        for (s, l, ds, dl), (_s, _l, ds2, dl2) in zip(raw, isis):
            print(f"| {s:g}, {l:g} | {ds:+.3f}, {dl:+.3f} | {ds2:+.4f}, {dl2:+.4f} |")
    import test_label_corners as arb

    for name in ("kaguya_mi", "kaguya_tc"):  # JAXA's corner coordinates in the labels as the arbiter
        rows = arb.arbiter(realdata, generic, name)
        print(f"\n{name}: JAXA's points in each reading's image, minus the pixel they name\n\n"
              "| point (pixel it names) | JAXA's point in our image - pixel (samples, lines) | ours, m | in ale's image - pixel "
              "| ale, m |\n"
              "| --- | --- | --- | --- | --- |")
        for key, s, l, ds, dl, m, ds2, dl2, m2 in rows:
            print(f"| {key} ({s:g}, {l:g}) | {ds:+.3f}, {dl:+.3f} | {m:.1f} | {ds2:+.3f}, {dl2:+.3f} | {m2:.1f} |")
        if len(rows) > 3:
            print(f"| after an affine fit, largest residual | {arb.affine_residual(rows, 0):.4f} px | "
                  f"| {arb.affine_residual(rows, 1):.4f} px | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
