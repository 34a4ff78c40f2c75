"""A small CSM-style projection of ale ISDs (``tests/data/ale/*/..._isd.json.gz``), independent of lunaralbedo's cameras.

Follows the USGS CSM frame and line-scanner sensor models as ale's ISDs feed them (image
coordinates 0-based with the first pixel centre at 0.5, i.e. ISIS - 0.5):

* time: frame camera ``center_ephemeris_time``; line scanner ``center + t_k + rate_k *
  (line - line_k + 0.5)`` from ``line_scan_rate = [[line_k, t_k, rate_k], ...]``;
* spacecraft: ``instrument_position`` (J2000 km, Moon-centred) interpolated linearly;
* rotations: SPICE quaternions (scalar first, J2000 -> frame), normalised linear
  interpolation, then the ``constant_rotation`` (row-major);
* focal plane: ``detSample = sample * summing + starting_detector_sample``, ``detLine =
  frac(line) * summing + starting_detector_line`` (a line scanner) or ``line * summing +
  start`` (a frame camera); ``(t1, t2) = (detLine - center_line - L0, detSample -
  center_sample - S0)`` through the inverse of ``[[L1, L2], [S1, S2]]`` gives ``(x, y)`` mm;
* distortion: ``radial`` (``u = d (1 - (k0 + k1 r^2 + k2 r^4))``) or ``kaguyalism``
  (``u = d + boresight + poly(r)`` with ``r = sqrt(x^2 + y^2)``);
* look ``(ux, uy, f)`` in the sensor frame, onto the 1737.4 km sphere.

``isis_conventions`` switches the few places where ISIS's camera plugins read the same IK
differently from ale (documented in docs/ingest.md); the tests use both.
"""
from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np

RADIUS_KM = 1737.4


def load_isd(path: str | Path) -> dict:
    with gzip.open(path, "rt") as f:
        return json.load(f)


def _q2m(q):
    s, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
                     [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
                     [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)]])


def _interp_rows(times, rows, t):
    times, rows = np.asarray(times, dtype=np.float64), np.asarray(rows, dtype=np.float64)
    if len(times) == 1:
        return rows[0]
    i = int(np.clip(np.searchsorted(times, t) - 1, 0, len(times) - 2))  # linear, extrapolated past the ends
    u = (t - times[i]) / (times[i + 1] - times[i])
    return rows[i] + u * (rows[i + 1] - rows[i])


def rotation(block: dict, t: float) -> np.ndarray:
    """Matrix J2000 -> the block's final frame at ``t`` (time-dependent quaternion, then constant rotation)."""
    q = _interp_rows(block["ephemeris_times"], block["quaternions"], t)
    m = _q2m(q)
    if block.get("constant_rotation") is not None:
        m = np.asarray(block["constant_rotation"], dtype=np.float64).reshape(3, 3) @ m
    return m


def image_time(isd: dict, line: float) -> float:
    if "line_scan_rate" not in isd:
        return float(isd["center_ephemeris_time"])
    rates = isd["line_scan_rate"]
    k = max(i for i, r in enumerate(rates) if r[0] <= line or i == 0)
    l0, t0, rate = rates[k]
    return float(isd["center_ephemeris_time"] + t0 + rate * (line - l0 + 0.5))


def _nk(isd, name):
    code = next(k.split("_")[0][3:] for k in isd["naif_keywords"] if k.startswith("INS") and k.endswith("_FOCAL_LENGTH"))
    return isd["naif_keywords"][f"INS{code}_{name}"]


def focal_plane(isd: dict, line: float, sample: float, isis_conventions: bool = False):
    """Distorted focal-plane ``(x, y)`` mm of CSM image coordinates (ale's detector, or ISIS's from the IK)."""
    ls = "line_scan_rate" in isd
    if isis_conventions:
        return isis_focal_plane(isd, line, sample)
    det_s = sample * isd["detector_sample_summing"] + isd["starting_detector_sample"]
    frac = line - np.floor(line) if ls else line
    det_l = frac * isd["detector_line_summing"] + isd["starting_detector_line"]
    c_s, c_l = isd["detector_center"]["sample"], isd["detector_center"]["line"]
    s, l = isd["focal2pixel_samples"], isd["focal2pixel_lines"]
    t1, t2 = det_l - c_l - l[0], det_s - c_s - s[0]
    m = np.array([[l[1], l[2]], [s[1], s[2]]], dtype=np.float64)
    x, y = np.linalg.solve(m, np.array([t1, t2]))
    return x, y


#: ISIS detector origins by sensor (the plugins' SetDetectorOrigin): (sample, line) from the IK or fixed
def _isis_origin(isd):
    name = isd["name_sensor"]
    if name.startswith("Multiband"):  # KaguyaMiCamera: (CENTER[0], CENTER[1] - 1)
        c = _nk(isd, "CENTER")
        return c[0], c[1] - 1.0
    if name.startswith("Terrain Camera"):  # KaguyaTcCamera
        return 2048.5, 1.0
    if "TMC" in name:  # Chandrayaan2TmcCamera: CENTER
        c = _nk(isd, "CENTER")
        return c[0], c[1]
    return _nk(isd, "BORESIGHT_SAMPLE"), _nk(isd, "BORESIGHT_LINE")  # UvvisCamera


def isis_focal_plane(isd, line, sample):
    """ISIS: detector sample = ISIS sample (= CSM + 0.5; first detector sample 1, no summing in
    these test images); detector line = ISIS line for a frame camera, 0 for a line scanner;
    offsets from the origin through the IK's TRANSX/TRANSY."""
    o_s, o_l = _isis_origin(isd)
    det_l = 0.0 if "line_scan_rate" in isd else line + 0.5
    ds, dl = sample + 0.5 - o_s, det_l - o_l
    tx, ty = _nk(isd, "TRANSX"), _nk(isd, "TRANSY")
    return tx[0] + tx[1] * ds + tx[2] * dl, ty[0] + ty[1] * ds + ty[2] * dl


def undistort(isd: dict, x: float, y: float, isis_conventions: bool = False):
    od = isd["optical_distortion"]
    if isis_conventions and isd["name_sensor"] == "UVVIS":  # ISIS ClementineUvvisDistortionMap from the IK
        xp, yp = _nk(isd, "PP")
        k1, k2, k3 = _nk(isd, "OD_K")
        p1, p2 = _nk(isd, "DECENTER")
        xx, yy = x - xp, y - yp
        rr = xx * xx + yy * yy
        dr = k1 + k2 * rr + k3 * rr * rr
        return x + xx * dr + p1 * (rr + 2 * xx * xx) + 2 * p2 * xx * yy, y + yy * dr + 2 * p1 * xx * yy + p2 * (rr + 2 * yy * yy)
    if "radial" in od:
        k = list(od["radial"]["coefficients"]) + [0.0] * 3
        r2 = x * x + y * y
        d = k[0] + r2 * (k[1] + r2 * k[2])
        return x * (1 - d), y * (1 - d)
    if "kaguyalism" in od:
        kx, ky = od["kaguyalism"]["x"], od["kaguyalism"]["y"]
        bx, by = od["kaguyalism"]["boresight_x"], od["kaguyalism"]["boresight_y"]
        r = np.hypot(x, y)
        if isis_conventions and isd["name_sensor"].startswith("Multiband"):
            r = y  # KaguyaMiCameraDistortionMap: the IK's signed along-line distance
        if isis_conventions and isd["name_sensor"].startswith("Terrain Camera"):
            bx = by = 0.0  # KaguyaTcCameraDistortionMap adds no boresight
        px = sum(c * r**i for i, c in enumerate(kx))
        py = sum(c * r**i for i, c in enumerate(ky))
        return x + px + bx, y + py + by
    raise ValueError(f"distortion {list(od)} not handled by this test routine")


def ground_point(isd: dict, line: float, sample: float, isis_conventions: bool = False):
    """``(point, t)``: body-fixed km point on the sphere seen at CSM image ``(line, sample)``
    (the ISD's body frame) and its image time (s, TDB)."""
    t = image_time(isd, line)
    return _ground_at(isd, t, line, sample, isis_conventions), t


def _ground_at(isd, t, line, sample, isis_conventions):
    """The sphere point seen at time ``t`` through the focal-plane position of CSM ``(line, sample)``."""
    ip = isd["instrument_position"]
    pos = _interp_rows(ip["ephemeris_times"], ip["positions"], t)
    x, y = focal_plane(isd, line, sample, isis_conventions)
    ux, uy = undistort(isd, x, y, isis_conventions)
    look = np.array([ux, uy, isd["focal_length_model"]["focal_length"]])
    j2000 = rotation(isd["instrument_pointing"], t).T @ (look / np.linalg.norm(look))
    body = rotation(isd["body_rotation"], t)
    o, d = body @ pos, body @ j2000
    b = o @ d
    tt = -b - np.sqrt(b * b - (o @ o - RADIUS_KM**2))
    return o + tt * d


def image_point(isd: dict, point, line: float, sample: float, isis_conventions: bool = False):
    """CSM ``(line, sample)`` whose pixel centre sees the body-fixed ``point`` (km, the ISD's body frame).

    Newton steps from ``(line, sample)``; a line scanner's time follows the line while its
    detector line stays at the pixel centre (the CSM ``frac(line)`` would make the map jump
    between lines)."""
    point = np.asarray(point, dtype=np.float64)
    frac = 0.5 if "line_scan_rate" in isd else None

    def g(x):
        return _ground_at(isd, image_time(isd, x[0]), x[0] if frac is None else frac, x[1], isis_conventions)

    x = np.array([line, sample], dtype=np.float64)
    for _ in range(30):
        p, h = g(x), 1e-3
        jac = np.stack([(g(x + [h, 0.0]) - p) / h, (g(x + [0.0, h]) - p) / h], axis=1)
        step = np.linalg.lstsq(jac, point - p, rcond=None)[0]
        x = x + step
        if np.abs(step).max() < 1e-7:
            break
    return float(x[0]), float(x[1])


def body_vector(isd: dict, key: str, t: float) -> np.ndarray:
    """``instrument_position`` or ``sun_position`` at ``t`` in the body-fixed frame (km)."""
    block = isd[key]
    return rotation(isd["body_rotation"], t) @ _interp_rows(block["ephemeris_times"], block["positions"], t)


def corners_and_centre(isd: dict) -> list[tuple[float, float]]:
    """CSM ``(line, sample)`` of the four corner pixel centres and the image centre."""
    nl, ns = isd["image_lines"], isd["image_samples"]
    return [(0.5, 0.5), (0.5, ns - 0.5), (nl - 0.5, 0.5), (nl - 0.5, ns - 0.5), (nl // 2 + 0.5, ns // 2 + 0.5)]


class IsdEphemeris:
    """An ephemeris (lunaralbedo's interface: body-fixed km, camera -> body matrices) read from an ISD.

    For TMC-2, whose CK slice is too large to keep in the repository: our camera then gets the
    ISD's positions and pointing, and the comparison checks its timing, detector and focal plane.
    """

    def __init__(self, isd: dict):
        self.isd = isd

    def spacecraft(self, et):
        return np.array([body_vector(self.isd, "instrument_position", t) for t in np.ravel(et)]).reshape(np.shape(et) + (3,))

    def sun(self, et):
        return np.array([body_vector(self.isd, "sun_position", t) for t in np.ravel(et)]).reshape(np.shape(et) + (3,))

    def camera_to_body(self, et):
        out = [rotation(self.isd["body_rotation"], t) @ rotation(self.isd["instrument_pointing"], t).T for t in np.ravel(et)]
        return np.array(out).reshape(np.shape(et) + (3, 3))
