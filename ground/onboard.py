"""The flight software run on the ground: one detection result -> FPGA packet -> the MCU's
:class:`lodestar.firmware.pipeline.StarTracker` -> attitude, over a star database built and
cached for the camera.  Shared by ``lodestar demo`` and ``lodestar solve``.

Units and conventions: ``docs/conventions.md``; stage timings in
milliseconds of wall clock.  Also how each camera preset is run in flight (exposure and the
detector's fixed-threshold registers, :data:`SETTINGS`; the reasons are in
``docs/camera_settings.md``).
"""

import math
import time
from pathlib import Path

from lodestar import contract as C
from lodestar.firmware.camera import Camera
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import DEFAULT_TOLERANCE_PX, Settings
from lodestar.firmware.starid.search import DEFAULT_MAX_WORK
from lodestar.ground import cache, codec, solve
from lodestar.sim import scene

DEFAULT_MAX_MAG = 6.0
"""Faintest catalogue star (V) of the database, as the flight database of the tests."""

FLIGHT_DENSITY = {"verification_stars_per_fov": 30, "pattern_stars_per_fov": 8,
                  "max_pair_fraction": 0.64}
"""The flight database's selection (:func:`lodestar.ground.database.build_database`
arguments): about 30 stars and 8 pattern stars per field of the stars to
:data:`DEFAULT_MAX_MAG`, pairs up to 0.64 of the FOV diagonal.  The estcube2 Pyramid
database shrinks from 519,700 B to 128 KiB with the same availability at rest and 2 deg/s
(``benchmarks/bench_flight_db.py``; sizes and numbers in ``docs/stardb.md``)."""


def firmware_camera(cam):
    """The MCU camera model of a ``lodestar.sim.camera.Camera`` (a preset)."""
    return Camera(cam.width, cam.height, cam.fx_px, cam.fy_px, cam.cx, cam.cy, cam.k1, cam.k2,
                  cam.k3, cam.p1, cam.p2)


def star_database(camera, max_mag=DEFAULT_MAX_MAG, method="pyramid", label="",
                  log=None, density=FLIGHT_DENSITY):
    """``(Database, path or None)`` for the firmware ``camera``: read from the cache of
    :func:`lodestar.ground.cache.load_database`, or built and cached there.  What happens is said on
    ``log`` (a text stream, None for silence): the start, then whether the database was
    built (and where it was cached, how long it took) or read from the cache.  ``label``
    names the camera in those lines.  ``density``: stars per field (:data:`FLIGHT_DENSITY`;
    None: every star to ``max_mag``).  Raises ``ValueError`` when no database can be built
    for this field of view and magnitude."""
    fov_h, fov_v = solve.camera_fov_deg(camera)
    depth = [] if max_mag is None else [f"V <= {max_mag:g}"]
    if density:
        depth.append(f"{density['verification_stars_per_fov']:g} stars per field")
    what = f"star database{' for ' + label if label else ''} (FOV {fov_h:.2f} x " \
           f"{fov_v:.2f} deg, {', '.join(depth)}, {method})"
    if log is not None:
        print(f"lodestar: loading the {what}; the first run builds it ...", file=log,
              flush=True)
    directory = cache.default_cache_dir()
    before = set(directory.glob("*.lsdb")) if directory.is_dir() else set()
    t0 = time.time_ns()
    db, path = cache.load_database(fov_h, fov_v, max_mag, method, density=density)
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
    FOV when that is larger (as :func:`lodestar.ground.solve.solve_centroids`)."""
    fov_h, _ = solve.camera_fov_deg(camera)
    return max(DEFAULT_TOLERANCE_PX, math.radians(fov_h) / 1000.0 * camera.fx)


def process(result, camera, database, omega=None, exposure_s=None, row_time_s=0.0,
            tolerance_px=None, method="pyramid", max_work=DEFAULT_MAX_WORK,
            velocity_km_s=None, prior=None, dt=None):
    """Send a detection ``result`` (``lodestar.golden.DetectionResult``) through the packet
    codec and the flight pipeline.

    Returns ``(packet_bytes, Result, timings)``: the FPGA packet, the
    :class:`lodestar.firmware.pipeline.Result` and ``{"packet": ms, "solve": ms,
    "firmware": {stage: ms}}``.  ``omega``: body rate (rad/s, camera frame; the gyro) or
    None; ``exposure_s``, ``row_time_s``: s, for smear and rate compensation;
    ``velocity_km_s``: the observer's (ICRS) for the aberration, or None; ``prior``, ``dt``:
    the flight loop's previous attitude and the time since it (tracking), or None.  Raises
    ``AssertionError`` if the packet does not decode to ``result`` (a codec bug)."""
    t0 = time.perf_counter()
    data = codec.encode(result)
    if codec.decode(data) != result:
        raise AssertionError("the packet round trip changed the detection result")
    t1 = time.perf_counter()
    tracker = StarTracker(database, camera, Settings(
                          method=method, exposure_s=exposure_s,
                          row_time_s=row_time_s, clock=time.perf_counter, max_work=max_work,
                          tolerance_px=(default_tolerance_px(camera) if tolerance_px is None
                                        else tolerance_px)))
    res = tracker.process(data, prior=prior, omega=omega, dt=dt,
                          velocity_km_s=velocity_km_s)
    t2 = time.perf_counter()
    timings = {"packet": (t1 - t0) * 1e3, "solve": (t2 - t1) * 1e3,
               "firmware": {k: v * 1e3 for k, v in res.timings.items()}}
    return data, res, timings


SETTINGS = {
    "preset": {},
    "tuned": {"estcube2": {"ksigma": 3.0},
              "lohmann": {"exposure_s": 0.2, "ksigma": 3.0, "min_pixels": 3}},
}
"""Camera settings per preset (why: docs/camera_settings.md): ``exposure_s`` (s), ``ksigma`` (the
fixed threshold ``T = B + ceil(ksigma sigma)``) and ``min_pixels`` (the detector's
register)."""

DEFAULT_SETTINGS = "tuned"


def camera_settings(preset, settings=DEFAULT_SETTINGS):
    """``{"exposure_s", "ksigma", "min_pixels"}`` of a preset under ``settings`` (a key of
    :data:`SETTINGS`); None for a value the preset and ``detector_config`` decide.  Raises
    ``ValueError`` for unknown settings."""
    if settings not in SETTINGS:
        raise ValueError(f"unknown settings {settings!r} (known: {', '.join(SETTINGS)})")
    values = {"exposure_s": None, "ksigma": None, "min_pixels": None}
    values.update(SETTINGS[settings].get(preset, {}))
    return values


def detector_config(cam, settings, exposure_s=None):
    """The golden detector's registers for ``cam`` under ``settings`` (from
    :func:`camera_settings`) at ``exposure_s`` (s; default the settings', then the
    preset's): :func:`lodestar.sim.scene.detector_config` with ``min_pixels`` and, for
    ``ksigma``, ``T = B + max(ceil(ksigma sigma), 1)`` where sigma is the dark-frame noise
    of that function's model (read noise, dark current and sky)."""
    t = exposure_s or settings["exposure_s"] or cam.exposure_s
    changes = {}
    if settings["min_pixels"] is not None:
        changes["min_pixels"] = settings["min_pixels"]
    cfg = scene.detector_config(cam, t, **changes)
    if settings["ksigma"] is not None:
        dark_e = (cam.dark_current_e_per_s + scene.SKY_E_PER_PX_S) * t
        sigma_adu = cam.gain_adu_per_e * math.sqrt(cam.read_noise_e ** 2 + dark_e)
        step = max(int(math.ceil(settings["ksigma"] * sigma_adu)), 1)
        cfg = cfg.replace(threshold=min(cfg.background + step, C.full_scale(cam.pixel_bits)))
    return cfg
