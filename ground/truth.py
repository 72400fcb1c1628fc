"""Checks of a firmware solution against the simulator's truth, shared by ``lodestar demo``
and the campaigns (``lodestar campaign``).

* The attitude error is the rotation ``A_sol A_true^T`` as a rotation vector in the camera
  frame, in arcsec: ``x``, ``y`` (cross-boresight components; ``cross`` = their root sum
  square, the boresight's pointing error), ``roll`` (about the boresight) and ``total``
  (its norm).
* A solution is **wrong** (:func:`judge`) when it names a record's star wrongly (a wrong
  match, below: a misidentification), or when its attitude is more than
  :data:`WRONG_ARCSEC` off *and* further off than :data:`WRONG_SIGMAS` times its own
  1-sigma on some axis (cross-boresight per axis, or roll): an attitude its covariance
  does not cover.  A solution of right matches more than ``WRONG_ARCSEC`` off but within
  its claimed uncertainty (a few smeared stars at high rate: a roll 1-sigma of minutes of
  arc) is **imprecise**: right, and counted apart so that it is seen.
* A match ``(record index, x, y, HIP)`` is **right** when the star of that HIP number was
  seen inside the record's bounding box grown by :data:`MATCH_MARGIN_PX` pixels: its
  visible track (``lodestar.sim.scene.visible_tracks``, the path it drew during the
  exposure, rolling shutter included) passes through that box.  At rest the track is a
  point; in a smeared frame a record can be one fragment of a broken streak, whose box
  need not hold the streak's centroid.

Quaternions, frames and pixel coordinates: ``docs/conventions.md``.
"""

import math

from lodestar.sim import catalogue

WRONG_ARCSEC = 180.0
"""A solution further than this (0.05 deg, the tests' criterion) from the truth is wrong
unless its covariance covers the error (:func:`judge`)."""

WRONG_SIGMAS = 5.0
"""An error beyond this many of the solution's own 1-sigma on an axis is not covered."""

MATCH_MARGIN_PX = 2
"""A match is right when its star's visible track passes through the record's bounding box
grown by this many pixels."""

TRACK_STEP_PX = 0.25
"""Spacing of the points at which a track is tested against a box, px."""

ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


def attitude_error_arcsec(q_solution, q_truth):
    """Error of ``q_solution`` against ``q_truth`` (scalar-last quaternions, ``v_cam = A(q)
    v_icrs``): ``{"x", "y", "cross", "roll", "total"}`` in arcsec, the rotation vector of
    ``A_sol A_true^T`` in the camera frame (``cross = hypot(x, y)``, ``total`` its norm)."""
    from scipy.spatial.transform import Rotation

    err = Rotation.from_quat(q_solution) * Rotation.from_quat(q_truth).inv()
    x, y, z = err.as_rotvec() * ARCSEC_PER_RAD
    return {"x": float(x), "y": float(y), "cross": float(math.hypot(x, y)),
            "roll": float(z), "total": float(math.sqrt(x * x + y * y + z * z))}


def judge(error, sigma_cross, sigma_roll, wrong_matches):
    """``(wrong, imprecise)`` of a solution (module docstring): ``error`` as
    :func:`attitude_error_arcsec` returns it, ``sigma_cross`` (per axis) and ``sigma_roll``
    the solution's 1-sigma in arcsec (None or not finite: no covariance, nothing covered),
    ``wrong_matches`` the count of wrongly named records."""
    if wrong_matches:
        return True, False
    if error["total"] <= WRONG_ARCSEC:
        return False, False
    covered = sigma_cross is not None and sigma_roll is not None and \
        math.isfinite(sigma_cross) and math.isfinite(sigma_roll) and \
        max(abs(error["x"]), abs(error["y"])) <= WRONG_SIGMAS * sigma_cross and \
        abs(error["roll"]) <= WRONG_SIGMAS * sigma_roll
    return not covered, covered


def track_meets_box(track, box):
    """Whether the polyline ``track`` (``[[x, y], ...]``, px) passes through the closed box
    ``(x0, y0, x1, y1)``: its points and points every :data:`TRACK_STEP_PX` along each
    segment are tested."""
    x0, y0, x1, y1 = box
    for i, (ax, ay) in enumerate(track):
        bx, by = track[i + 1] if i + 1 < len(track) else (ax, ay)
        steps = max(int(math.ceil(math.hypot(bx - ax, by - ay) / TRACK_STEP_PX)), 1)
        for k in range(steps + 1):
            x = ax + (bx - ax) * k / steps
            y = ay + (by - ay) * k / steps
            if x0 <= x <= x1 and y0 <= y <= y1:
                return True
    return False


def match_rows(matches, records, sources):
    """One row per match with the truth verdict: ``matches`` are ``(record index, x, y,
    HIP)`` (``lodestar.firmware.pipeline.Result.matches``), ``records`` the packet's blob
    records, ``sources`` the truth's sources (``lodestar.sim.scene.simulate``).  Each row:
    ``record``, ``x``, ``y``, ``hip``, ``name``, ``vmag`` (None for a HIP number missing
    from the catalogue), ``right`` and ``truth_offset_px`` (None when the simulator did not
    render that star)."""

    cat = catalogue.load()
    by_hip = {s["hip"]: s for s in sources if s["kind"] == "star"}
    rows = []
    for index, x, y, hip in matches:
        rec = records[index]
        src = by_hip.get(hip)
        m = MATCH_MARGIN_PX
        box = (rec.xmin - m, rec.ymin - m, rec.xmax + m, rec.ymax + m)
        right = src is not None and track_meets_box(src.get("track") or
                                                    [[src["x"], src["y"]]], box)
        try:
            vmag = float(cat.vmag[cat.by_hip(hip)])
        except KeyError:
            vmag = None
        rows.append({"record": index, "x": x, "y": y, "hip": hip, "name": cat.name(hip),
                     "vmag": vmag, "right": bool(right),
                     "truth_offset_px": None if src is None else
                     math.hypot(x - src["x"], y - src["y"])})
    return rows
