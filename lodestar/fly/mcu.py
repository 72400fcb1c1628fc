"""The MCU's time per frame in the twin: F401 estimates from the Cortex-M4F build's
measurements in the docs, per frame class, so that the slow frames make the loop miss sensor
frames as the flight loop would.  Every figure is an estimate (the docs carry ±30-50 %).

- Lost in space (``process`` without a prior): Pyramid's p50 on estcube2, 348 ms at rest and
  412 ms moving (``docs/firmware.md``, F401 estimate per packet class).
- Tracking (with a prior): ``TRACK_BASE_MS + TRACK_PER_RECORD_MS x records``, the line through
  the budgeted frame (10 records, 73 ms) and the frame with every blob (50 records, 243 ms)
  of ``docs/firmware.md`` (tracking frame by frame).
- The idle-time hook before each tracking frame's wait (``StarTracker.prefetch`` with a
  prior): ``HOOK_MS``, its collection (the one a tracking frame would otherwise make; the
  model above is of frames that query their own cone, so a refill is counted there).
- The executive's step around ``process`` (status, packet, prior, telemetry, watchdog, the
  gyro ring and the ``min_sum`` write-back): ``LOOP_MS``, derived from the icount units
  measured on the Cortex-M4F build (:data:`STEP_UNITS`, ``docs/mcu_board.md``) with that
  build's F401 calibration (:func:`f401_ms`).  The SPI wire time is the bus's own
  (``lodestar.fly.bus``), the two-wire bus's likewise.
"""

import math

from lodestar.regress import mcutime

STEP_UNITS = {"step": 2837, "min_sum": 447}
"""icount units (``time.ticks_us`` under ``-icount shift=0``) of the executive on the
Cortex-M4F build (``benchmarks/bench_executive.py``: its link reading a 10-record packet from
the link model, whose own share is subtracted; ``docs/mcu_board.md``, the table of the link
and executive): one step around a ``process`` that returns at once, the gyro ring's sample
and the fused attitude's update included, and ``min_sum`` written back."""
REFERENCE_UNITS = {"bm_float": 11759, "bm_nqueens": 119831}
"""icount units of the two calibration calls (``mcutime.CALLS``) on the representation-A
twin of the same build (``docs/mcu_board.md``): with ``mcutime.F401_US`` the F401's time per
unit."""


def f401_ms(units):
    """F401 estimate (ms) of ``units`` icount units on the Cortex-M4F build: scaled by the
    geometric mean over the calibration calls of the published F401 time over their units
    (about 3.18 us per unit)."""
    logs = [math.log(mcutime.F401_US[name] / REFERENCE_UNITS[name]) for name in REFERENCE_UNITS]
    return units * math.exp(sum(logs) / len(logs)) / 1000.0


LIS_REST_MS = 348.0
LIS_MOVING_MS = 412.0
MOVING_RAD_S = 0.0017
"""Above this gyro rate (0.1 deg/s) a lost-in-space frame costs the moving class's time."""
TRACK_BASE_MS = 30.5
TRACK_PER_RECORD_MS = 4.25
LOOP_MS = f401_ms(sum(STEP_UNITS.values()))
"""The executive's share of a frame (about 10.4 ms)."""
HOOK_MS = 10.3
"""The idle-time hook with a prior when its held cone covers the next frame: its collection
(``benchmarks/bench_mcu.py --stages-only``, the hook's later calls, 10.2-10.5 ms;
``docs/mcu_board.md``, Speed and heap of the tracking frames)."""


def process_ms(result, prior, omega):
    """Estimated F401 milliseconds of one ``StarTracker.process`` call."""
    if prior is None:
        moving = omega is not None and sum(w * w for w in omega) > MOVING_RAD_S ** 2
        return LIS_MOVING_MS if moving else LIS_REST_MS
    return TRACK_BASE_MS + TRACK_PER_RECORD_MS * getattr(result, "n_records", 0)


class TimedTracker:
    """A ``StarTracker`` whose ``process`` also spends the estimated MCU time on the twin's
    clock (``advance(ms)``), plus ``hang_ms`` once when set (a stuck loop that does not feed
    the watchdog).  ``settings``, ``status`` and ``reason`` are the tracker's."""

    def __init__(self, tracker, advance):
        self.tracker = tracker
        self.advance = advance
        self.hang_ms = 0
        self.last_ms = 0.0

    @property
    def settings(self):
        return self.tracker.settings

    @property
    def status(self):
        return self.tracker.status

    @property
    def reason(self):
        return self.tracker.reason

    def prefetch(self, prior=None, omega=None, dt=None):
        """The tracker's idle-time hook, spending :data:`HOOK_MS` when given a prior."""
        code = self.tracker.prefetch(prior, omega, dt)
        if prior is not None:
            self.advance(HOOK_MS)
        return code

    def process(self, packet, prior=None, omega=None, dt=None):
        result = self.tracker.process(packet, prior=prior, omega=omega, dt=dt)
        ms = process_ms(result, prior, omega) + LOOP_MS
        if self.hang_ms:
            ms += self.hang_ms
            self.hang_ms = 0
        self.last_ms = ms
        self.advance(ms)
        return result
