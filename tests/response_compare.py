"""Side-by-side with OpenCV's ``calibrateDebevec`` / ``calibrateRobertson`` (the reference methods).

Used by the tests and ``benchmarks/response_bench.py`` on the same synthetic stacks as
:func:`lunaralbedo.response.synthetic.render_stack`; not part of the product.
"""
from __future__ import annotations

import numpy as np

from lunaralbedo.response.model import log_rms_error

#: DN range of the comparison (the issue's figure of merit).
EVAL_RANGE = (10, 245)


def opencv_response(dn: np.ndarray, exposure: np.ndarray, method: str) -> np.ndarray:
    """g over 0..255 from OpenCV (grey images copied into 3 channels; NaN where OpenCV gives none)."""
    import cv2

    imgs = [np.repeat(im.astype(np.uint8)[..., None], 3, axis=2) for im in dn]
    times = np.asarray(exposure, np.float32)
    cal = cv2.createCalibrateDebevec() if method == "debevec" else cv2.createCalibrateRobertson()
    g = cal.process(imgs, times)[:, 0, 0].astype(np.float64)
    g[~(np.isfinite(g) & (g > 0))] = np.nan
    return g


def curve_error(lut: np.ndarray, truth, lo_hi=EVAL_RANGE) -> tuple[float, float]:
    """(log-RMS error after one global scale, fraction of DN covered) of a 256-entry g over ``lo_hi``."""
    z = np.arange(lo_hi[0], lo_hi[1] + 1)
    est = np.asarray(lut, np.float64)[z]
    ok = np.isfinite(est) & (est > 0)
    return log_rms_error(est[ok], truth.inverse(z[ok])), float(ok.mean())
