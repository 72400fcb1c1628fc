"""Checks of a firmware solution against the simulator's truth, shared by ``lodestar demo``
and the campaigns (``lodestar campaign``).

* The attitude error is the rotation ``A_sol A_true^T`` as a rotation vector in the camera
  frame, in arcsec: ``x``, ``y`` (cross-boresight components; ``cross`` = their root sum
  square, the boresight's pointing error), ``roll`` (about the boresight) and ``total``
  (its norm).  Quaternions are scalar last with ``v_cam = A(q) v_icrs`` (``lodestar.sim``).
* A solution is **wrong** when ``total`` exceeds :data:`WRONG_ARCSEC`.
* A match ``(record index, x, y, HIP)`` is **right** when the simulator placed the star of
  that HIP number inside the record's bounding box grown by :data:`MATCH_MARGIN_PX` pixels
  (pixel coordinates as ``lodestar.contract``: ``x`` column, ``y`` row, pixel centres at
  integer indices).
"""

import math

WRONG_ARCSEC = 180.0
"""A solution further than this (0.05 deg, the tests' criterion) from the truth is wrong."""

MATCH_MARGIN_PX = 2
"""A match is right when its star's true centroid lies inside the record's bounding box
grown by this many pixels."""

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


def match_rows(matches, records, sources):
    """One row per match with the truth verdict: ``matches`` are ``(record index, x, y,
    HIP)`` (``lodestar.firmware.pipeline.Result.matches``), ``records`` the packet's blob
    records, ``sources`` the truth's sources (``lodestar.sim.scene.simulate``).  Each row:
    ``record``, ``x``, ``y``, ``hip``, ``name``, ``vmag`` (None for a HIP number missing
    from the catalogue), ``right`` and ``truth_offset_px`` (None when the simulator did not
    render that star)."""
    from lodestar.sim import catalogue

    cat = catalogue.load()
    by_hip = {s["hip"]: s for s in sources if s["kind"] == "star"}
    rows = []
    for index, x, y, hip in matches:
        rec = records[index]
        src = by_hip.get(hip)
        m = MATCH_MARGIN_PX
        right = src is not None and rec.xmin - m <= src["x"] <= rec.xmax + m and \
            rec.ymin - m <= src["y"] <= rec.ymax + m
        try:
            vmag = float(cat.vmag[cat.by_hip(hip)])
        except KeyError:
            vmag = None
        rows.append({"record": index, "x": x, "y": y, "hip": hip, "name": cat.name(hip),
                     "vmag": vmag, "right": bool(right),
                     "truth_offset_px": None if src is None else
                     math.hypot(x - src["x"], y - src["y"])})
    return rows
