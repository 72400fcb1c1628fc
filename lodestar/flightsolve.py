"""The flight software run on the ground: one detection result -> FPGA packet -> the MCU's
:class:`lodestar.firmware.pipeline.StarTracker` -> attitude, over a star database built and
cached for the camera.  Shared by ``lodestar demo`` and ``lodestar solve``.

Units and conventions: those of ``lodestar.firmware.pipeline`` (pixels as
``lodestar.contract``, ``q = [x, y, z, w]`` scalar last with ``v_cam = A(q) v_icrs``, rates
in rad/s in the camera frame, times in seconds, sigmas in arcseconds); stage timings in
milliseconds of wall clock.
"""

import math
import time
from pathlib import Path

from lodestar import packet
from lodestar import solve as ground_solve
from lodestar.firmware.camera import Camera
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import DEFAULT_TOLERANCE_PX, Settings

DEFAULT_MAX_MAG = 6.0
"""Faintest catalogue star (V) of the database, as the flight database of the tests."""


def firmware_camera(cam):
    """The MCU camera model of a ``lodestar.sim.camera.Camera`` (a preset)."""
    return Camera(cam.width, cam.height, cam.fx_px, cam.fy_px, cam.cx, cam.cy, cam.k1, cam.k2,
                  cam.k3, cam.p1, cam.p2)


def star_database(camera, max_mag=DEFAULT_MAX_MAG, method="pyramid", label="",
                  log=None):
    """``(Database, path or None)`` for the firmware ``camera``: read from the cache of
    :func:`lodestar.solve.load_database`, or built and cached there.  What happens is said on
    ``log`` (a text stream, None for silence): the start, then whether the database was
    built (and where it was cached, how long it took) or read from the cache.  ``label``
    names the camera in those lines.  Raises ``ValueError`` when no database can be built
    for this field of view and magnitude."""
    fov_h, fov_v = ground_solve.camera_fov_deg(camera)
    what = f"star database{' for ' + label if label else ''} (FOV {fov_h:.2f} x " \
           f"{fov_v:.2f} deg, V <= {max_mag:g}, {method})"
    if log is not None:
        print(f"lodestar: loading the {what}; the first run builds it ...", file=log,
              flush=True)
    directory = ground_solve.default_cache_dir()
    before = set(directory.glob("*.lsdb")) if directory.is_dir() else set()
    t0 = time.time_ns()
    db, path = ground_solve.load_database(fov_h, fov_v, max_mag, method)
    dt = (time.time_ns() - t0) * 1e-9
    # built: not cached, a new file, or a corrupt file rewritten just now
    built = path is None or Path(path) not in before or Path(path).stat().st_mtime_ns >= t0
    if log is not None:
        if built:
            where = f"cached in {path}" if path else "not cached (cache directory not writable)"
            print(f"lodestar: built the {what} in {dt:.1f} s: {db.n_stars} stars; {where}",
                  file=log, flush=True)
        else:
            print(f"lodestar: read the star database from the cache {path}", file=log,
                  flush=True)
    return db, path


def default_tolerance_px(camera):
    """Match tolerance for a camera, px: the pipeline's default, or 1/1000 of the horizontal
    FOV when that is larger (as :func:`lodestar.solve.solve_centroids`)."""
    fov_h, _ = ground_solve.camera_fov_deg(camera)
    return max(DEFAULT_TOLERANCE_PX, math.radians(fov_h) / 1000.0 * camera.fx)


def process(result, camera, database, omega=None, exposure_s=None, row_time_s=0.0,
            tolerance_px=None, method="pyramid"):
    """Send a detection ``result`` (``lodestar.golden.DetectionResult``) through the packet
    codec and the flight pipeline.

    Returns ``(packet_bytes, Result, timings)``: the FPGA packet, the
    :class:`lodestar.firmware.pipeline.Result` and ``{"packet": ms, "solve": ms,
    "firmware": {stage: ms}}``.  ``omega``: body rate (rad/s, camera frame; the gyro) or
    None; ``exposure_s``, ``row_time_s``: s, for smear and rate compensation.  Raises
    ``AssertionError`` if the packet does not decode to ``result`` (a codec bug)."""
    t0 = time.perf_counter()
    data = packet.encode(result)
    if packet.decode(data) != result:
        raise AssertionError("the packet round trip changed the detection result")
    t1 = time.perf_counter()
    tracker = StarTracker(database, camera, Settings(
                          method=method, exposure_s=exposure_s,
                          row_time_s=row_time_s, clock=time.perf_counter,
                          tolerance_px=(default_tolerance_px(camera) if tolerance_px is None
                                        else tolerance_px)))
    res = tracker.process(data, omega=omega)
    t2 = time.perf_counter()
    timings = {"packet": (t1 - t0) * 1e3, "solve": (t2 - t1) * 1e3,
               "firmware": {k: v * 1e3 for k, v in res.timings.items()}}
    return data, res, timings
