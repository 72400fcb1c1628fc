"""Scripted fakes of the executive's surroundings, in plain Python that MicroPython runs too
(no f-strings, dataclasses or typing): a clock, a watchdog that records the longest gap
between feeds, a link that plays a script of frames, a sensor, a tracker whose results and
solve times are scripted (or verified results with sigmas, ``result``), and a persistent
store."""

import math

from lodestar import contract as C
from lodestar.firmware import link as _link
from lodestar.firmware import quaternion
from lodestar.firmware import status as S


class Clock(object):
    def __init__(self):
        self.now = 0

    def ticks_ms(self):
        return self.now

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, n):
        self.now += n


class Watchdog(object):
    """``feed()`` records the longest interval between two feeds (ms of the clock)."""

    def __init__(self, clock):
        self.clock = clock
        self.last = clock.now
        self.max_gap = 0
        self.feeds = 0

    def feed(self):
        gap = self.clock.now - self.last
        if gap > self.max_gap:
            self.max_gap = gap
        self.last = self.clock.now
        self.feeds += 1


# link script items
OK_FRAME = "ok"            # a good packet
TIMEOUT = "timeout"        # no irq within the wait
STATUS_BAD = "status"      # the status word fails its CRC
CRC = "crc"                # the packet fails its CRC-32
CLOCK_LOST = "clock"       # the status word shows OVF_CLOCK_LOST
RESTART = "restart"        # a good packet after a detector reset the MCU did not command
READ_MS = 6                # a frame's status + packet read
BUILD = 0x5A               # the gateware build byte the link reads
FRAME_MS = 100             # the sensor's frame period: frame k's first pixel at k x 100 ms


class Link(object):
    """Plays ``script`` (a list of the items above), one per frame read; past its end the irq
    is dead.  The sensor's frame ``k`` has its first pixel (and, with no rows, its IRQ edge)
    at ``k * FRAME_MS`` of the clock: a wait ends at the next one (its frame counter ``k``
    less the frames before a restart, its header timestamp ``k * FRAME_MS`` ms in us), so
    the frames that pass while the MCU works are skipped ones, as the gateware numbers and
    stamps them."""

    def __init__(self, clock, script, id_ok=True, reg_ok=True, build=BUILD):
        self.clock = clock
        self.ident = (C.LINK_VERSION, build)
        self.script = list(script)
        self.pos = 0
        self.item = None
        self.id_ok = id_ok
        self.reg_ok = reg_ok
        self.counter = 0
        self.base = 0              # frames before the last restart
        self.stamp = 0
        self.offset_us = 0         # the gateware's microsecond counter at the clock's 0
        self.last_frame_counter = None
        self.last_stamp = None
        self.last_stamp_top = 0
        self.writes = []
        self.resyncs = 0
        self.soft_resets = 0
        self.overflow = 0
        self.counters = [0] * _link.N_COUNTERS
        self.irq_edge = False
        self.restarted = False
        self.last_height = 0
        self.flags = 0             # the frame flags of the next packet read
        self.last_flags = 0

    def read_id(self):
        return _link.OK if self.id_ok else _link.ID_BAD

    def write_reg(self, name, value):
        self.writes.append((name, value))
        return _link.OK if self.reg_ok else _link.VERIFY_FAILED

    def resync(self):
        self.resyncs += 1
        return _link.OK

    def soft_reset(self):
        self.soft_resets += 1
        return _link.OK

    def wait_irq(self, timeout_ms, tick=None):
        """The irq rises at the next frame's first pixel (``irq_edge``), or never (a
        timeout)."""
        self.irq_edge = False
        if self.pos >= len(self.script):
            self.item = TIMEOUT
        else:
            self.item = self.script[self.pos]
            self.pos += 1
        if self.item == TIMEOUT:
            self.clock.sleep_ms(timeout_ms)
            return False
        k = self.clock.now // FRAME_MS + 1
        self.clock.sleep_ms(k * FRAME_MS - self.clock.now)
        self.counter = k - self.base
        self.stamp = k * FRAME_MS * 1000 + self.offset_us
        self.irq_edge = True
        return True

    def read_status(self):
        self.overflow = 64 if self.item == CLOCK_LOST else 0
        if self.item == RESTART:
            self.base += self.counter
            self.counter = 0
            self.restarted = True
        return _link.STATUS_BAD if self.item == STATUS_BAD else _link.OK

    def clock_lost(self):
        return self.item == CLOCK_LOST

    def read_packet(self):
        self.clock.sleep_ms(READ_MS)
        if self.item == CRC:
            return _link.PACKET_CRC, 0
        self.last_frame_counter = self.counter
        self.last_stamp = self.stamp & 0x3FFFFFFF          # as the link gives it
        self.last_stamp_top = (self.stamp >> 30) & 3
        self.last_flags = self.flags
        return _link.OK, 3

    def packet(self, n):
        return b"packet"


class Sensor(object):
    """``start`` answers from ``starts`` (a list of booleans; past its end: True) and takes
    40 ms; ``timing`` gives a 36.4 us row and a 0.1 s frame."""

    def __init__(self, clock, starts=()):
        self.clock = clock
        self.starts = list(starts)
        self.n_starts = 0
        self.configured = []
        self.row = 3.64e-05

    def start(self, settings):
        self.clock.sleep_ms(40)
        ok = self.starts[self.n_starts] if self.n_starts < len(self.starts) else True
        self.n_starts += 1
        if not ok:
            return S.BAD_INPUT, "bus: writing R0x0D failed (NACK)"
        return S.OK, ""

    def configure(self, **settings):
        self.configured.append(settings)
        return S.OK, ""

    def timing(self):
        return S.OK, "", (self.row, 2743 * self.row, 0.09998)


class Settings(object):
    def __init__(self):
        self.clock = None
        self.row_time_s = 0.0
        self.exposure_s = None
        self.epoch_s = 0.0
        self.max_stars = 30


class Result(object):
    def __init__(self, status, q=None, min_sum=0, t_epoch_s=None):
        self.status = status
        self.q = q
        self.t_epoch_s = t_epoch_s
        self.min_sum = min_sum
        self.matches = [(0, None, None, 1)] * (12 if q is not None else 0)
        self.n_records = 20
        self.sigma_cross_arcsec = 0.5 if q is not None else None
        self.sigma_roll_arcsec = 5.0 if q is not None else None
        self.reason = ""


Q0 = (0.0, 0.0, 0.6, 0.8)
Q_IMPRECISE = (0.0, 0.6, 0.0, 0.8)


def result(status, roll_arcsec=0.0, sigma_cross=20.0, sigma_roll=100.0, q=Q0):
    """A verified frame's result: ``q`` turned by ``roll_arcsec`` about the boresight
    (camera z) with its sigmas (arcsec): a ``Tracker`` outcome returned as it is."""
    h = 0.5 * math.radians(roll_arcsec / 3600.0)
    d = (0.0, 0.0, math.sin(h), math.cos(h))
    res = Result(status, tuple(quaternion.multiply(d, q)), min_sum=0, t_epoch_s=0.0)
    res.sigma_cross_arcsec = sigma_cross
    res.sigma_roll_arcsec = sigma_roll
    return res


class Tracker(object):
    """``outcomes``: per frame a status (``S.OK`` gives ``Q0``) or ``"raise"``; past its end
    every frame solves.  A solve takes ``solve_ms`` (lost in space) or ``track_ms`` (with
    a prior), calling ``settings.clock`` at ``stages`` boundaries as the pipeline does; an
    attitude holds for ``t_epoch_s`` (s after the start of row 0's exposure)."""

    def __init__(self, clock, outcomes=(), status=S.OK, solve_ms=700, track_ms=80, stages=6):
        self.clock = clock
        self.outcomes = list(outcomes)
        self.status = status
        self.reason = "database CRC" if status != S.OK else ""
        self.settings = Settings()
        self.solve_ms = solve_ms
        self.track_ms = track_ms
        self.stages = stages
        self.calls = []
        self.prefetches = []
        self.t_epoch_s = 0.0

    def prefetch(self, prior=None, omega=None, dt=None):
        """The idle-time hook: its arguments kept in ``prefetches``."""
        self.prefetches.append((prior, omega, dt))
        return S.OK

    def process(self, packet, prior=None, omega=None, dt=None):
        self.calls.append((prior, omega, dt))
        k = len(self.calls) - 1
        outcome = self.outcomes[k] if k < len(self.outcomes) else S.OK
        spent = self.solve_ms if prior is None else self.track_ms
        for _ in range(self.stages):
            self.clock.sleep_ms(spent // self.stages)
            if self.settings.clock is not None:
                self.settings.clock()
        if outcome == "raise":
            raise ValueError("scripted")
        if isinstance(outcome, Result):
            return outcome
        if outcome == S.OK:
            return Result(S.OK, Q0, min_sum=1000 + k, t_epoch_s=self.t_epoch_s)
        res = Result(outcome)
        if outcome == S.IMPRECISE:      # the pipeline keeps its attitude for diagnostics
            res.q, res.min_sum = Q_IMPRECISE, 2000 + k
        return res


class Store(object):
    def __init__(self):
        self.data = None
        self.writes = 0

    def read(self):
        return self.data

    def write(self, data):
        self.data = bytes(data)
        self.writes += 1
