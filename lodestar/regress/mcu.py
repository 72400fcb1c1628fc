"""The firmware side of the regression (``lodestar regress``): one recorded FPGA packet
through the flight API, reduced to plain data.  Runs unchanged on CPython and MicroPython
(``run.mjs`` copies it to ``/lib/lodestar/``), so both interpreters execute the same calls.

    db = open_database("/regress/estcube2.lsdb")
    tracker = make_tracker(db, camera_settings, "pyramid")
    out = replay(tracker, packet_bytes, case_inputs)

The ``camera_settings`` and ``case_inputs`` fields and the JSON-ready :func:`outcome` fields:
``docs/regression.md``, MCU-side replay; units as ``docs/conventions.md``.
"""

from lodestar.firmware import database as _database
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings


def open_database(path):
    """The :class:`lodestar.firmware.database.Database` of the image file ``path``, read by
    offset as on the MCU (raises ``DatabaseError`` for a bad image)."""
    return _database.Database.open(path)


def make_tracker(database, settings, method):
    """A :class:`StarTracker` for lost-in-space ``method`` over ``database`` with the camera
    ``settings`` (``docs/regression.md``)."""
    return StarTracker(database, settings["camera"], Settings(method=method,
                       exposure_s=settings["exposure_s"], row_time_s=settings["row_time_s"],
                       tolerance_px=settings["tolerance_px"]))


def outcome(result):
    """The comparable content of a pipeline ``Result`` (``docs/regression.md``)."""
    matches = []
    for index, _x, _y, hip in result.matches:
        matches.append([index, hip])
    return {
        "status": result.status, "status_name": result.status_name,
        "reason": result.reason, "mode": result.mode, "n_records": result.n_records,
        "n_stars": result.n_stars, "matches": matches,
        "q": None if result.q is None else [float(c) for c in result.q],
        # the instant q holds for (a baseline firmware from before it has none)
        "t_epoch_s": getattr(result, "t_epoch_s", None),
        "sigma_cross_arcsec": result.sigma_cross_arcsec,
        "sigma_roll_arcsec": result.sigma_roll_arcsec,
        "centroid_sigma_px": result.centroid_sigma_px,
        "patterns_tried": result.patterns_tried,
        # a baseline firmware from before the record budget (benchmarks/bench_mcu.py) has none
        "min_sum": getattr(result, "min_sum", 0),
    }


def process(tracker, packet, inputs):
    """``tracker.process`` of one recorded ``packet`` (bytes) with the case ``inputs``
    (``docs/regression.md``): the pipeline's ``Result``."""
    return tracker.process(packet, prior=inputs.get("prior"), omega=inputs.get("omega"),
                           dt=inputs.get("dt"), exposure_s=inputs.get("exposure_s"))


def replay(tracker, packet, inputs):
    """:func:`outcome` of :func:`process`."""
    return outcome(process(tracker, packet, inputs))
