"""The flight executive: the MCU's main loop as a bounded state machine; never raises.

    exe = Executive(link, tracker, clock=time, sensor=cam, sensor_settings=settings,
                    watchdog=machine.WDT(timeout=8000), store=store, gyro=gyro,
                    telemetry=downlink, now_s=obc_time)
    while True:
        exe.step()                    # one frame (or one recovery or safe-mode action)

States (``STATE_NAMES``): ``BOOT`` (restore the prior, check the gateware ID and the star
database) -> ``CONFIGURE`` (sensor start-up, the row time and exposure the sensor's
registers give written into the tracker's settings, gateware registers written and read
back) -> ``ACQUIRE`` (lost in space) <-> ``TRACK`` (the last attitude as the prior) ->
``COAST`` (up to ``coast_frames`` bad frames in a row: the last good attitude is kept
and carried on the gyro rate, ``process(prior=q, omega, dt)``, instead of dropping to lost
in space) -> ``RECOVER`` -> ``SAFE``.  A frame: the tracker's idle-time hook (its
``prefetch``: the next frame's catalogue cone made before the wait), wait for ``irq`` (at most
``irq_timeout_ms``), read and check the status word, read the packet (the link checks
length and CRC and resynchronises after a bad read), ``StarTracker.process``, write
``min_sum`` back (read back), emit the telemetry record, keep the attitude with its time
and a CRC in the persistent ``store``.

Recovery escalates while faults persist (``recover_after`` link faults in a row per level):
1 resynchronise the link (flush + drain), 2 soft-reset the detector, 3 start the sensor
again (PLL, settings, ``min_sum`` of the track kept; also at once on the status word's
``OVF_CLOCK_LOST``), 4 ``SAFE``: no frames are processed until a ``CMD_RESET`` or
``CMD_MODE`` command.  A good frame resets the level.  After a failed attempt the next one
waits for the next frame (one frame period), so each level gets a new frame before the next.
A detector reset the MCU did not command (its frame counter restarts) is counted
(``uncommanded_reset``).

Time: every frame is dated by its packet header's ``timestamp`` (the gateware's microsecond
counter latched at its first pixel, ``contract.TIMESTAMP_HZ``; the link gives its low 30 bits,
small ints on the MCU, and differences are taken modulo 2**30: valid up to 2**29 us, 537 s),
mapped to the MCU's ticks by a correlation taken from the frames whose IRQ edge the wait saw
(the edge less the read-out); the edge and the frame counter are cross-checks (a
disagreement beyond :data:`_TIME_TOLERANCE_MS`, or a counter step the timestamps do not
show, is counted: ``time_mismatch``), and the timestamps tell the frames never read
(``missed``).  The gyro is sampled into a ring while the loop waits and at every watchdog
feed; a frame's rate is the ring's at the frame's epoch (its first pixel less the exposure,
plus ``Settings.epoch_s``).  An attitude's time tag is the instant of its result's
``t_epoch_s`` (spacecraft ms, and ``epoch_us`` on the gateware's clock), and ``dt`` of the
next frame's prior runs from that instant (by the timestamps; by the time tags for a prior
restored after a reset).  A frame whose stars contradict the gyro's rate
(``RATE_CONTRADICTED``) is counted and coasted over like a bad frame (the prior is kept:
the stars matched, only the rate is in doubt), and the next :data:`DISTRUST_FRAMES` frames
go without the gyro's rate (each fits its own).  An ``IMPRECISE`` frame (its attitude's
5 sigma beyond ``Settings.max_error_arcsec``) is not adopted on its own: it is fused (below),
and without a good attitude (``ACQUIRE``) it guides the next frame: that frame tracks from
it (``guide``; a tracking frame verifies its own identification and falls back to lost in
space), a tenth of a lost-in-space frame's time, so a fast spin that solves only loosely
is still read at the frame rate.  Fused attitude: every verified frame (``OK`` or
``IMPRECISE``, finite sigmas) updates ``fq``, the last one carried on the gyro to its epoch
and combined per camera axis with the frame's (sigma cross, sigma roll) by a Kalman filter
of the carried error and its drift on the gyro (``f_drift``; the declared gyro error:
``gyro_bias_rad_s``, ``gyro_noise_rad_s``, ``gyro_bias_walk``); an axis beyond the gate
(``fuse_gate``, a chi-square) restarts it from the frame.  When its 5 sigma bound
``5 sqrt(2 sc^2 + sr^2)`` is within ``Settings.max_error_arcsec`` it is adopted as the
attitude (``adopted`` 2, ``TRACK``; the record's sigmas are the fused ones, its status the
frame's); an ``OK`` frame is adopted fused (never looser).  Dropped by
``RATE_CONTRADICTED``, a coast past ``coast_frames``, a commanded acquire, a database
change and a boot; restarted by a gap over ``fuse_gap_s`` or a frame without the gyro's
rate (``docs/mcu_board.md``).  The watchdog (``feed()``; ``machine.WDT`` on the MCU) is fed
at every stage boundary and, through ``Settings.clock``, at every stage boundary inside
``process``.

Telemetry: one record of ``contract.telemetry.BYTES`` per step, packed into one
preallocated buffer (its layout: :mod:`lodestar.contract.telemetry`) and handed to
``telemetry(buf)``.  Commands (:meth:`Executive.command`, queued, applied at the next step):
``CMD_MODE`` (``MODE_AUTO``, ``MODE_SAFE``, ``MODE_ACQUIRE``), ``CMD_EXPOSURE`` (seconds),
``CMD_GAIN`` (sensor steps), ``CMD_SETTING`` (a tracker setting by name), ``CMD_DATABASE``
(a slot, through ``select_database(slot)`` that returns a new tracker or None; the slot is
kept in the persistent record, so a reset boots the ground's choice), ``CMD_RESET``.

Injected objects (all optional but ``link``, ``tracker`` and ``clock``): ``clock`` with
``ticks_ms``/``ticks_diff``/``sleep_ms``; ``now_ms()`` spacecraft time in integer ms (the
time tags; the clock's ticks when absent; integers, as a float32 cannot hold it);
``gyro()`` the body rate (rad/s, camera frame) or None;
``store`` with ``read()`` -> bytes or None and ``write(bytes)`` (RTC backup registers or
F-RAM; :data:`PRIOR_FORMAT`: the last attitude and the database slot); ``mem_free()`` for
the heap figure (``gc.mem_free``).
Pure Python for CPython and MicroPython; its buffers are allocated once, and a step allocates
only short-lived small objects besides ``process`` (320 bytes on the Cortex-M4F build, the
link's share included: views, the CRC-32s, the gyro's rate; the 32-bit timestamps are taken
modulo 2**32 without a long mask, so they make long ints only above 2**30).  Board wiring,
formats and measurements: ``docs/mcu_board.md``.
"""

import math
import struct
from array import array

try:
    from micropython import const
except ImportError:         # CPython
    def const(value):
        return value

from lodestar.contract import telemetry
from lodestar.contract.packet import FRAME_LINE_ERROR, FRAME_TIMEOUT, FRAME_TRUNCATED, crc32

from . import link as _link
from . import status as S
from .geometry import RAD_TO_ARCSEC
from .quaternion import from_rotation_vector, multiply, unit_quaternion

BOOT = 0
CONFIGURE = 1
ACQUIRE = 2
TRACK = 3
COAST = 4
RECOVER = 5
SAFE = 6
STATE_NAMES = ("BOOT", "CONFIGURE", "ACQUIRE", "TRACK", "COAST", "RECOVER", "SAFE")

CMD_MODE = 1
CMD_EXPOSURE = 2
CMD_GAIN = 3
CMD_SETTING = 4
CMD_DATABASE = 5
CMD_RESET = 6
MODE_AUTO = 0
MODE_SAFE = 1
MODE_ACQUIRE = 2
_COMMAND_QUEUE = const(4)    # commands held between two steps (more: ``command`` -> False)

# recovery levels
LEVEL_NONE = 0
LEVEL_RESYNC = 1
LEVEL_DETECTOR = 2
LEVEL_SENSOR = 3
LEVEL_SAFE = 4

# health counters (indices into Executive.health, in telemetry.HEALTH_NAMES' order; const:
# not kept in the module's globals on the MCU)
_H_FRAMES = const(0)           # frames read whole
_H_OK = const(1)               # frames solved
_H_BAD = const(2)              # frames not solved (any status)
_H_IRQ_TIMEOUT = const(3)      # waits for a frame that timed out
_H_LINK_FAULT = const(4)       # status or packet reads refused
_H_COASTED = const(5)          # frames carried on the gyro
_H_LOST = const(6)             # tracks dropped to lost in space
_H_RESYNC = const(7)           # recoveries at level 1
_H_DETECTOR_RESET = const(8)   # recoveries at level 2
_H_SENSOR_INIT = const(9)      # sensor start-ups (the first included)
_H_SAFE = const(10)            # entries into SAFE
_H_CLOCK_LOST = const(11)      # status words with OVF_CLOCK_LOST
_H_SENSOR_FAULT = const(12)    # sensor start-ups or writes that failed (NACK, read-back)
_H_REG_FAULT = const(13)       # gateware register writes that did not read back
_H_COMMANDS = const(14)        # commands applied
_H_INTERNAL = const(15)        # exceptions caught in a step
_H_RESTART = const(16)         # detector resets the MCU did not command (frame counter restarted)
_H_RATE_CONTRADICTED = const(17)   # frames whose stars contradicted the gyro's rate
_H_TIME_MISMATCH = const(18)   # header timestamps that disagree with the IRQ edge or frame counter
_H_MISSED = const(19)          # sensor frames never read (timestamp gaps between two packets)
HEALTH_NAMES = telemetry.HEALTH_NAMES
N_HEALTH = telemetry.N_HEALTH

_GYRO_RING = const(32)
_GYRO_EVERY_MS = const(20)
"""Gyro samples kept (at most one every ``_GYRO_EVERY_MS``, taken while waiting for a frame
and at every watchdog feed): 0.64 s or more of rate history, so a frame's rate is read at
its exposure, not when its packet is processed (up to half a second later after a lost in
space solve)."""
_TIME_TOLERANCE_MS = const(5)
"""Largest disagreement between the first pixel dated by the header's ``timestamp`` (through
the correlation of the gateware's microseconds with the MCU's ticks) and by the frame's IRQ
edge less its read-out (the edge is polled every 1 ms, and the IRQ rises within a fraction
of a millisecond after the last row): beyond it the edge is counted as a mismatch
(``time_mismatch``) and the timestamp's date kept."""
CUT_FLAGS = FRAME_TRUNCATED | FRAME_TIMEOUT | FRAME_LINE_ERROR
"""Frame flags of a frame the sensor did not deliver whole: the gateware ended it itself (its
stall timeout's dark rows, or the next frame's start), so its IRQ edge is not its first
pixel plus the read-out and neither checks nor renews the timestamp's correlation."""
HALF_RANGE = 0x80000000
"""Half the range of the 32-bit frame counter: differences below it count forwards."""
_STAMP_MASK = const(0x3FFFFFFF)    # timestamps are kept modulo 2**30 (small ints on the MCU)
_STAMP_HALF = const(0x20000000)    # differences below 2**29 us (537 s) count forwards
DISTRUST_FRAMES = 10
"""Frames processed without the gyro's rate after one whose stars contradicted it
(``RATE_CONTRADICTED``): the frame then fits its own rate; the gyro is tried again after."""
GYRO_BIAS_RAD_S = 8.7e-05
"""Declared gyro bias per axis (rad/s; 0.005 deg/s, the twin's gyro model,
``lodestar.fly.trajectory``): the starting sigma of the fused attitude's drift on the gyro,
per axis."""
GYRO_NOISE_RAD_S = 3.5e-05
"""Declared white noise of one gyro sample per axis (rad/s; 0.002 deg/s): added in
quadrature, times ``dt``."""
GYRO_BIAS_WALK = 1.0e-05
"""Declared random walk of the gyro's bias (rad/s per root second; 0.0006 deg/s in a second,
an estimate for a MEMS rate sensor: a bias instability of about 0.004 deg/s over 100 s):
how fast the fused attitude's drift estimate may go stale."""
FUSE_GATE = 16.0
"""Largest chi-square, per axis, of the rotation between the fused attitude carried to a frame
and the frame's own, against their combined variance (4 sigma): beyond it the fused estimate
restarts from the frame (a wrong gyro or a wrong frame is never averaged in)."""
FUSE_GAP_S = 1.0
"""Longest time (s) the fused attitude is carried on the gyro to the next verified frame;
beyond it the estimate restarts from the frame."""
_PACE_MAX_MS = const(1000)
"""Longest wait between a failed attempt and the next (one frame period, capped)."""

_HEAP_EVERY = const(16)
"""Steps between two ``mem_free()`` calls (it walks the heap: on the Cortex-M4F build it costs
more than the rest of a step's telemetry); the records between repeat the last figure."""
PRIOR_FORMAT = ">4fQII"
"""The record kept across a reset (32 bytes: 8 of the RTC's backup registers, or F-RAM): q
(x, y, z, w; NaN without an attitude), its time tag (ms), the star-database slot the ground
selected (0 until it selects one), CRC-32 (``contract.crc32``) of the bytes before it."""
PRIOR_BYTES = struct.calcsize(PRIOR_FORMAT)
SLOT_MAX = 0xFFFF
"""Largest star-database slot a ``CMD_DATABASE`` selects (``BAD_INPUT`` beyond)."""
_RECORD_BYTES = telemetry.BYTES     # (``telemetry`` is a parameter name in the constructor)
NAN = float("nan")
_NO_Q = (NAN, NAN, NAN, NAN)
"""The quaternion of the records without an attitude (made once: no tuple per step)."""


def _count(array_, index, n=1):
    value = array_[index] + n
    array_[index] = value if value < 0xFFFF else 0xFFFF


class Executive(object):
    """The flight loop (module docstring).  ``sensor_settings``: the dict for
    ``sensor.start``; ``registers``: gateware registers ``{name: value}`` written at
    configuration; ``frame_s``: the frame period (s; from the sensor's timing when it has
    one); ``irq_timeout_ms``: the longest wait for a frame; ``coast_frames``: bad frames
    carried on the gyro before the track is dropped; ``recover_after``: link faults in a
    row before the next recovery level; ``max_prior_age_s``: oldest stored attitude used
    after a reset; ``build``: the gateware build byte this software expects
    (``contract.build_id`` of the board's configuration; None: not checked): a gateware of
    another build puts the loop in ``SAFE`` at boot.  ``gyro_bias_rad_s``,
    ``gyro_noise_rad_s``, ``gyro_bias_walk``: the declared gyro error per axis (rad/s; the
    walk rad/s per root second) that grows the fused attitude's variances; ``fuse_gate``:
    the chi-square per axis beyond which a frame restarts it; ``fuse_gap_s``: the longest
    time it is carried to the next frame (module docstring)."""

    def __init__(self, link, tracker, clock, sensor=None, sensor_settings=None, registers=None,
                 watchdog=None, store=None, gyro=None, telemetry=None, now_ms=None,
                 mem_free=None, select_database=None, frame_s=0.1, irq_timeout_ms=250,
                 coast_frames=5, recover_after=3, max_prior_age_s=10.0, build=None,
                 gyro_bias_rad_s=GYRO_BIAS_RAD_S, gyro_noise_rad_s=GYRO_NOISE_RAD_S,
                 gyro_bias_walk=GYRO_BIAS_WALK, fuse_gate=FUSE_GATE, fuse_gap_s=FUSE_GAP_S):
        self.link = link
        self.build = build
        self.tracker = tracker
        self.clock = clock
        self.sensor = sensor
        self.sensor_settings = sensor_settings if sensor_settings is not None else {}
        self.registers = registers if registers is not None else {}
        self.watchdog = watchdog
        self.store = store
        self.gyro = gyro
        self.telemetry = telemetry
        self.now_ms = now_ms
        self.mem_free = mem_free
        self.select_database = select_database
        self.frame_s = frame_s
        self.irq_timeout_ms = irq_timeout_ms
        self.coast_frames = coast_frames
        self.recover_after = recover_after
        self.max_prior_age_s = max_prior_age_s
        self.gyro_bias_rad_s = gyro_bias_rad_s
        self.gyro_noise_rad_s = gyro_noise_rad_s
        self.gyro_bias_walk = gyro_bias_walk
        self.fuse_gate = fuse_gate
        self.fuse_gap_s = fuse_gap_s
        self.health = array("H", [0] * N_HEALTH)
        self.record = bytearray(_RECORD_BYTES)
        self._record_body = memoryview(self.record)[:_RECORD_BYTES - 4]
        self._prior_buf = bytearray(PRIOR_BYTES)
        self._prior_body = memoryview(self._prior_buf)[:PRIOR_BYTES - 4]
        self._commands = [None] * _COMMAND_QUEUE
        self._n_commands = 0
        self.state = BOOT
        self.mode = MODE_AUTO
        self.level = LEVEL_NONE
        self.faults = 0               # link faults in a row
        self.bad = 0                  # bad frames in a row (solve failures included)
        self.q = None                 # last good attitude
        self.q_time = 0               # its time tag (its result's t_epoch_s), spacecraft ms
        self.q_counter = 0            # its FPGA frame counter
        self.q_stamp = 0              # its frame's FPGA timestamp (us), low 30 bits
        self._tops = 0                # the top 2 bits of q_stamp's and of q_epoch_us' (<< 2)
        self.q_epoch_us = None        # its time tag on the FPGA's clock (us; None: unknown)
        self.guide = None             # without q: the last frame's IMPRECISE attitude, its
                                      # time tag (ms) and epoch (us, low 30 bits; or None)
        self.fq = None                # the fused attitude (module docstring) or None
        self.f_var = array("f", [0.0] * 7)   # its covariance (``_combine``): per cross axis
        # the error (arcsec^2) and its drift (arcsec^2/s^2); roll, roll with its drift
        # (arcsec^2/s), its drift; the cross error with its drift (complex: real, imaginary)
        self.f_drift = array("f", [0.0] * 3)   # the drift on the gyro (arcsec/s, camera x y z)
        self.f_time = 0               # its time tag, spacecraft ms
        self.f_epoch = None           # its time tag on the FPGA's clock (us, low 30 bits)
        self.f_n = 0                  # frames fused since it (re)started
        self.adopted = 0              # the last frame's attitude adopted: 0 none, 1 its
                                      # own, 2 the fused one (``q_sigma`` then its sigmas)
        self.q_sigma = array("f", [NAN, NAN])   # adopted fused: sigma cross, roll (arcsec)
        self.slot = 0                 # the star-database slot (kept across a reset)
        self.distrust = 0             # frames left to process without the gyro's rate
        self.sequence = 0
        self.reason = ""
        self.last_status = S.OK
        self.last_link = _link.OK
        self.last_result = None
        self.min_sum = 0
        self.last_command = (0, S.OK)
        self.configured = False       # CONFIGURE completed since BOOT
        self.heap_free = 0            # the last mem_free() figure
        self._gyro_t = array("l", [0] * _GYRO_RING)         # ticks of each sample
        self._gyro_w = array("f", [0.0] * (3 * _GYRO_RING))  # rad/s, 3 per sample
        self._gyro_n = 0              # samples held
        self._gyro_at = 0             # the next slot
        self._tick = self._sample_gyro   # wait_irq's poll hook, bound once
        self._attempt = 0             # ticks the current attempt began (its IRQ seen)
        self._retry = None            # a failed attempt's ticks: the next waits a frame
        self._sync = [None, 0, 0.0]   # [timestamp, ticks, ms]: a first pixel's stamp and
                                      # its MCU ticks (an IRQ edge less ms of read-out);
                                      # stamp None: no correlation (updated in place)
        self._last = [None, None]     # [frame counter, timestamp] of the last packet read
                                      # (counter None: none; updated in place)
        self._wrapped = None
        self._wrap_clock()

    # ---- helpers -------------------------------------------------------------------------

    def _wrap_clock(self):
        """Feed the watchdog at the stage boundaries inside ``process`` (``Settings.clock``
        is called there)."""
        try:
            settings = getattr(self.tracker, "settings", None)
            if settings is None or self._wrapped is self.tracker:
                return
            inner = settings.clock
        except Exception:
            return
        self._wrapped = self.tracker
        clock = self.clock

        def fed():
            self.feed()
            return inner() if inner is not None else clock.ticks_ms()
        settings.clock = fed

    def feed(self):
        if self.watchdog is not None:
            try:
                self.watchdog.feed()
            except Exception:
                pass
        self._sample_gyro()

    def _sample_gyro(self):
        """Keep a gyro sample in the ring (at most one every ``_GYRO_EVERY_MS``)."""
        if self.gyro is None:
            return
        clock = self.clock
        now = clock.ticks_ms()
        last = (self._gyro_at - 1) % _GYRO_RING
        if self._gyro_n and clock.ticks_diff(now, self._gyro_t[last]) < _GYRO_EVERY_MS:
            return
        try:
            w = self.gyro()
            k = 3 * self._gyro_at
            self._gyro_w[k] = w[0]
            self._gyro_w[k + 1] = w[1]
            self._gyro_w[k + 2] = w[2]
        except Exception:
            return
        self._gyro_t[self._gyro_at] = now
        self._gyro_at = (self._gyro_at + 1) % _GYRO_RING
        if self._gyro_n < _GYRO_RING:
            self._gyro_n += 1

    def _rate_at(self, age_ms, now):
        """The gyro's rate ``age_ms`` before ticks ``now``: linear between the two samples
        around that instant, the nearest sample outside them; None without a sample."""
        clock = self.clock
        ts = self._gyro_t
        ws = self._gyro_w
        after = None
        j = (self._gyro_at - 1) % _GYRO_RING
        for _ in range(self._gyro_n):
            if clock.ticks_diff(now, ts[j]) >= age_ms:
                break
            after = j
            j = (j - 1) % _GYRO_RING
        else:
            j = None
        if j is None and after is None:
            return None
        if j is None or after is None:
            k = 3 * (after if j is None else j)
            return (ws[k], ws[k + 1], ws[k + 2])
        span = clock.ticks_diff(ts[after], ts[j])
        f = (clock.ticks_diff(now, ts[j]) - age_ms) / span if span > 0 else 0.0
        a = 3 * j
        b = 3 * after
        return (ws[a] + f * (ws[b] - ws[a]), ws[a + 1] + f * (ws[b + 1] - ws[a + 1]),
                ws[a + 2] + f * (ws[b + 2] - ws[a + 2]))

    def _date(self, counter, stamp, edge, now):
        """How long before ticks ``now`` the frame of ``counter`` stamped ``stamp`` had its
        first pixel (ms): by the timestamp through the correlation (module docstring), else by
        its IRQ edge (when this wait saw the line rise) less the read-out (rows x row time),
        else 0 (now).  Cross-checks, each counted as ``time_mismatch``: a timestamp that goes
        back, or that shows fewer frame periods since the last packet than the frame counter
        numbers frames, is wrong (the correlation and the prior's timestamp are dropped: the
        next edge makes a new one, ``dt`` comes from the time tags meanwhile); an edge more
        than :data:`_TIME_TOLERANCE_MS` later than the timestamp's date is ignored (an edge can
        only be late: a poll that found the line low between two queued packets) unless the
        timestamp also ran ahead of the counter (it jumped: dropped, the edge dates the
        frame); an edge that much earlier shows the correlation's own edge was late (a packet
        that emerged after a start-up's flush): this one dates the frame and anchors anew;
        the edge of a frame the gateware ended itself (:data:`CUT_FLAGS`) is no date.  An
        agreeing edge renews the correlation (the clocks drift).  The periods
        between two packets, less one, are the sensor frames never read (``missed``)."""
        frames, step = self._periods(counter, stamp)
        age = self._stamp_age(stamp, now)
        at_edge = None
        if edge and stamp is not None and not self.link.last_flags & CUT_FLAGS:
            try:
                settings = self.tracker.settings
                readout = self.link.last_height * settings.row_time_s * 1000.0
            except Exception:
                readout = 0.0
            at_edge = self.clock.ticks_diff(now, self._attempt) + readout
            if age is not None and abs(age - at_edge) > _TIME_TOLERANCE_MS:
                _count(self.health, _H_TIME_MISMATCH)
                if frames is not None and frames > step:
                    self._stamp_wrong()                    # the stamp jumped ahead
                    frames = age = None
                elif at_edge > age:
                    age = None                             # the anchor's edge was late
                else:
                    at_edge = None                         # a late edge: the stamp dates
            if at_edge is not None:
                sync = self._sync
                sync[0] = stamp
                sync[1] = self._attempt
                sync[2] = readout
        if frames is not None and frames > 1:
            _count(self.health, _H_MISSED, frames - 1)
        if age is not None:
            return age
        return at_edge if at_edge is not None else 0.0

    def _periods(self, counter, stamp):
        """``(frame periods, frame-counter step)`` since the last packet read, from the
        timestamps (None when they cannot tell, or are wrong: counted and dropped) and the
        counters (``HALF_RANGE`` or more: the counter restarted)."""
        last = self._last
        last_counter = last[0]
        last_stamp = last[1]
        last[0] = counter
        last[1] = stamp
        if last_counter is None or stamp is None or last_stamp is None or \
                not self.frame_s > 0:
            return None, HALF_RANGE
        gap = (stamp - last_stamp) & _STAMP_MASK
        step = counter - last_counter
        if step < 0:
            step += 0x100000000
        frames = int(gap / (1e6 * self.frame_s) + 0.5)
        if gap >= _STAMP_HALF or (step < HALF_RANGE and frames < step):
            _count(self.health, _H_TIME_MISMATCH)
            self._stamp_wrong()
            return None, step
        return frames, step

    def _stamp_age(self, stamp, now):
        """Ms before ticks ``now`` of the first pixel stamped ``stamp``, through the
        correlation; None without one."""
        sync = self._sync
        if stamp is None or sync[0] is None:
            return None
        d = (stamp - sync[0]) & _STAMP_MASK
        if d >= _STAMP_HALF:                 # signed, within half the 30-bit range
            d = d - _STAMP_MASK - 1
        return self.clock.ticks_diff(now, sync[1]) + sync[2] - d / 1000.0

    def _stamp_wrong(self):
        """The timestamps before this one no longer date anything."""
        self._sync[0] = None
        self.q_epoch_us = None
        self.f_epoch = None
        self.guide = None

    def _pace(self):
        """After a failed attempt the next one waits for the next frame (one frame period
        after the failed one began, at most ``_PACE_MAX_MS``): a burst of link errors then
        costs a frame per attempt and is ridden out by coasting, instead of running through
        every recovery level in microseconds while the IRQ stays high."""
        if self._retry is None:
            return
        clock = self.clock
        left = int(self.frame_s * 1000) - clock.ticks_diff(clock.ticks_ms(), self._retry)
        self._retry = None
        if left > 0:
            self.feed()
            clock.sleep_ms(min(left, _PACE_MAX_MS))
            self.feed()

    def time_ms(self):
        if self.now_ms is not None:
            try:
                return int(self.now_ms())
            except Exception:
                pass
        return self.clock.ticks_ms()

    def _enter(self, state, reason=""):
        if state == SAFE and self.state != SAFE:
            _count(self.health, _H_SAFE)
        self.state = state
        if reason:
            self.reason = reason

    # ---- commands ------------------------------------------------------------------------

    def command(self, code, arg=None, value=None):
        """Queue a command for the next step: True if queued (False: the queue is full)."""
        if self._n_commands >= _COMMAND_QUEUE:
            return False
        self._commands[self._n_commands] = (code, arg, value)
        self._n_commands += 1
        return True

    def _apply_commands(self):
        for i in range(self._n_commands):
            code, arg, value = self._commands[i]
            self._commands[i] = None
            self.last_command = (code, self._apply(code, arg, value))
            _count(self.health, _H_COMMANDS)
        self._n_commands = 0

    def _apply(self, code, arg, value):
        if code == CMD_MODE:
            if arg == MODE_SAFE:
                self.mode = MODE_SAFE
                self._enter(SAFE, "commanded")
            elif arg in (MODE_AUTO, MODE_ACQUIRE):
                self.mode = MODE_AUTO
                self.level = LEVEL_NONE
                self.faults = 0
                if arg == MODE_ACQUIRE:
                    self.q = self.guide = self.fq = None
                self._enter(CONFIGURE if self.state in (SAFE, BOOT) else ACQUIRE
                            if self.q is None else TRACK, "commanded")
            else:
                return S.BAD_INPUT
            return S.OK
        if code == CMD_EXPOSURE or code == CMD_GAIN:
            if self.sensor is None:
                return S.BAD_INPUT
            if code == CMD_EXPOSURE:
                settings = self._exposure_rows(arg)
                if settings is None:
                    return S.BAD_INPUT
            else:
                settings = {"gain": arg}
            st, reason = self.sensor.configure(**settings)
            if st != S.OK:
                _count(self.health, _H_SENSOR_FAULT)
                self.reason = reason
                return st
            self.sensor_settings.update(settings)
            self._read_timing()
            return S.OK
        if code == CMD_SETTING:
            settings = getattr(self.tracker, "settings", None)
            if settings is None or not isinstance(arg, str) or not hasattr(settings, arg) \
                    or arg.startswith("_") or arg == "clock":
                return S.BAD_INPUT
            setattr(settings, arg, value)
            return S.OK
        if code == CMD_DATABASE:
            st = self._select(arg)
            if st != S.OK:
                return st
            self.q = self.guide = self.fq = None
            self._save_prior()
            if self.state in (TRACK, COAST):
                self._enter(ACQUIRE)
            return S.OK
        if code == CMD_RESET:
            self.level = LEVEL_NONE
            self.faults = 0
            self.bad = 0
            self.mode = MODE_AUTO
            self._enter(BOOT, "commanded reset")
            return S.OK
        return S.BAD_INPUT

    def _exposure_rows(self, exposure_s):
        """Sensor settings for an exposure in s, from the row time the registers give."""
        timing = self._timing()
        if timing is None or not isinstance(exposure_s, (int, float)) or exposure_s <= 0:
            return None
        return {"exposure": max(1, int(exposure_s / timing[0] + 0.5))}

    # ---- persistent prior --------------------------------------------------------------

    def _save_prior(self):
        """Keep the attitude (NaN without one), its time tag and the database slot, with a
        CRC, in the persistent store."""
        if self.store is None:
            return
        buf = self._prior_buf
        q = self.q if self.q is not None else _NO_Q
        struct.pack_into(PRIOR_FORMAT, buf, 0, q[0], q[1], q[2], q[3], max(0, self.q_time),
                         self.slot, 0)
        struct.pack_into(">I", buf, PRIOR_BYTES - 4, crc32(self._prior_body))
        try:
            self.store.write(buf)
        except Exception:
            pass

    def _load_prior(self):
        """Restore the database slot from the store if its CRC matches, and the attitude too
        if it is young enough."""
        if self.store is None:
            return
        try:
            data = self.store.read()
        except Exception:
            return
        if data is None or len(data) != PRIOR_BYTES:
            return
        x, y, z, w, t, slot, crc = struct.unpack(PRIOR_FORMAT, data)
        if crc32(memoryview(data)[:PRIOR_BYTES - 4]) != crc:
            return
        self.slot = slot
        age = self.time_ms() - t
        if not 0 <= age <= 1000 * self.max_prior_age_s:
            return
        n = x * x + y * y + z * z + w * w
        if not 0.9 < n < 1.1:
            return
        self.q = (x, y, z, w)
        self.q_time = t
        self.q_counter = None         # the FPGA may have restarted: dt from the time tags
        self.q_epoch_us = None
        self.q_stamp = None

    def _select(self, slot):
        """Open database ``slot`` through ``select_database``: ``S.OK`` and the new tracker
        in use, or ``S.DATABASE_CORRUPT`` (or ``S.BAD_INPUT`` without the hook or for a slot
        outside 0..``SLOT_MAX``) and the tracker kept."""
        if self.select_database is None or not isinstance(slot, int) or \
                not 0 <= slot <= SLOT_MAX:
            return S.BAD_INPUT
        tracker = self.select_database(slot)
        if tracker is None or getattr(tracker, "status", S.OK) != S.OK:
            return S.DATABASE_CORRUPT
        self.tracker = tracker
        self.slot = slot
        self._wrap_clock()
        self._read_timing()
        return S.OK

    # ---- states --------------------------------------------------------------------------

    def step(self):
        """One step of the state machine (at most one frame); returns the state."""
        try:
            self.feed()
            self._apply_commands()
            state = self.state
            if state != SAFE and state != RECOVER:
                self._pace()
            self._attempt = self.clock.ticks_ms()
            if state == BOOT:
                self._boot()
            elif state == CONFIGURE:
                self._configure()
            elif state in (ACQUIRE, TRACK, COAST):
                self._frame()
            elif state == RECOVER:
                self._recover()
            else:
                self._safe()
        except MemoryError:
            _count(self.health, _H_INTERNAL)
            self.reason = "out of heap"
            self._fault()
        except Exception as exc:
            _count(self.health, _H_INTERNAL)
            try:
                self.reason = "internal: " + repr(exc)
            except Exception:
                self.reason = "internal"
            self._fault()
        self.feed()
        self._emit()
        return self.state

    def _boot(self):
        self.configured = False
        self.guide = self.fq = None
        self._load_prior()
        if self.slot and self._select(self.slot) != S.OK:    # the ground's choice, kept
            self.slot = 0
        tracker = self.tracker
        if getattr(tracker, "status", S.OK) != S.OK:
            self.last_status = tracker.status
            self._enter(SAFE, "database: " + getattr(tracker, "reason", ""))
            return
        code = _link.BUS_ERROR
        for _attempt in range(3):
            code = self.link.read_id()
            if code == _link.OK:
                break
        self.last_link = code
        if code != _link.OK:
            self._fault()
            self.reason = "gateware ID: " + _link.CODE_NAMES[code]
            return
        if self.build is not None and self.link.ident[1] != self.build:
            self._enter(SAFE, "gateware build 0x{:02X}, expected 0x{:02X}".format(
                self.link.ident[1], self.build))
            return
        self._enter(CONFIGURE)

    def _timing(self):
        if self.sensor is None:
            return None
        try:
            st, _reason, timing = self.sensor.timing()
        except Exception:
            return None
        return timing if st == S.OK else None

    def _read_timing(self):
        """Row time and exposure of the sensor's registers into the tracker's settings."""
        timing = self._timing()
        settings = getattr(self.tracker, "settings", None)
        if timing is None or settings is None:
            return
        settings.row_time_s = timing[0]
        settings.exposure_s = timing[1]
        self.frame_s = timing[2]

    def _configure(self):
        if self.sensor is not None:
            _count(self.health, _H_SENSOR_INIT)
            self.feed()
            st, reason = self.sensor.start(self.sensor_settings)
            self.feed()
            if st != S.OK:
                _count(self.health, _H_SENSOR_FAULT)
                self.reason = "sensor: " + reason
                self._fault(LEVEL_SENSOR)
                return
            self._read_timing()
        # min_sum: the track's own budget while there is an attitude (a re-init keeps it)
        min_sum = self.min_sum if self.q is not None else self.registers.get("min_sum", 0)
        for name in self.registers:
            value = min_sum if name == "min_sum" else self.registers[name]
            code = self.link.write_reg(name, value)
            if code != _link.OK:
                _count(self.health, _H_REG_FAULT)
                self.last_link = code
                self.reason = "register " + name + ": " + _link.CODE_NAMES[code]
                self._fault()
                return
        self.min_sum = min_sum
        self.link.resync()                     # start at a packet boundary
        self.configured = True
        self._enter(TRACK if self.q is not None else ACQUIRE)

    def _fault(self, at_least=LEVEL_NONE):
        """A link or system fault: escalate after ``recover_after`` in a row (the next
        attempt waits for the next frame: :meth:`_pace`)."""
        self._retry = self._attempt
        self.faults += 1
        level = self.level
        if self.faults >= self.recover_after:
            level += 1
            self.faults = 0
        if at_least > level:
            level = at_least
        if level > self.level:
            self.level = level
            self._enter(RECOVER)

    def _recover(self):
        level = self.level
        if level >= LEVEL_SAFE:
            self._enter(SAFE, self.reason)
            return
        if level == LEVEL_RESYNC:
            _count(self.health, _H_RESYNC)
            code = self.link.resync()
        elif level == LEVEL_DETECTOR:
            _count(self.health, _H_DETECTOR_RESET)
            code = self.link.soft_reset()
        else:
            self._enter(CONFIGURE)
            return
        self.last_link = code
        if not self.configured:
            self._enter(BOOT)
        else:
            self._enter(ACQUIRE if self.q is None else COAST)

    def _safe(self):
        """No frames: the watchdog fed, telemetry emitted, one frame period slept."""
        self.clock.sleep_ms(int(self.frame_s * 1000))

    def _restarted(self):
        """Count a detector reset the MCU did not command (the link saw the frame counter
        restart): the counters before it no longer number frames (the timestamp runs on)."""
        link = self.link
        if link.restarted:
            link.restarted = False
            _count(self.health, _H_RESTART)
            self._last[0] = None

    def _frame(self):
        link = self.link
        clock = self.clock
        self._prefetch()
        if not link.wait_irq(self.irq_timeout_ms, self._tick):
            _count(self.health, _H_IRQ_TIMEOUT)
            self.last_link = _link.IRQ_TIMEOUT
            self._bad_frame()
            self._fault()
            return
        self._attempt = clock.ticks_ms()
        edge = link.irq_edge
        self.feed()
        code = link.read_status()
        self._restarted()
        if code == _link.OK and link.clock_lost():
            _count(self.health, _H_CLOCK_LOST)
            self.last_link = code
            self.reason = "clock lost"
            self._bad_frame()
            self._fault(LEVEL_SENSOR)
            link.resync()
            return
        if code == _link.OK:
            code, n = link.read_packet()
            self._restarted()
        self.last_link = code
        if code != _link.OK:
            _count(self.health, _H_LINK_FAULT)
            self._bad_frame()
            self._fault()
            return
        _count(self.health, _H_FRAMES)
        self.faults = 0
        self._solve(n, edge)

    def _prefetch(self):
        """Before the wait: the tracker's idle-time hook (``StarTracker.prefetch``, when it
        has one) with what the next frame will pass to ``process``: the prior (the last
        attitude, else the guide; None drops the cone before a lost-in-space frame), the
        gyro's latest rate (none while distrusted) and ``dt`` from the prior's time tag to
        the next frame's epoch, estimated as the time since the tag, at least a frame
        period (the frame checks its cone against its own prior: an error of the estimate
        costs at most a query of its own).  Its status is not needed; a fault is ignored."""
        hook = getattr(self.tracker, "prefetch", None)
        if hook is None:
            return
        prior = self.q
        p_time = self.q_time
        if prior is None and self.guide is not None:
            prior, p_time = self.guide[0], self.guide[1]
        try:
            if prior is None:
                hook(None)
                return
            omega = None
            if not self.distrust:
                omega = self._rate_at(0, self.clock.ticks_ms())
            dt = (self.time_ms() - p_time) / 1000.0
            hook(prior, omega, dt if dt > self.frame_s else self.frame_s)
        except Exception:
            pass

    def _exposure_ms(self):
        """``(exposure ms, Settings.epoch_s)`` of the tracker's settings."""
        settings = getattr(self.tracker, "settings", None)
        try:
            return 1000.0 * (settings.exposure_s or 0.0), settings.epoch_s
        except Exception:
            return 0.0, 0.0

    def _solve(self, n, edge):
        """``process`` the packet read (``n`` records) with the prior carried from its time
        tag to this frame's epoch and the gyro's rate at that epoch (module docstring)."""
        link = self.link
        clock = self.clock
        counter = link.last_frame_counter
        stamp = link.last_stamp
        top = link.last_stamp_top
        ticks = clock.ticks_ms()
        now_ms = self.time_ms()
        first = self._date(counter, stamp, edge, ticks)
        exposure_ms, epoch_s = self._exposure_ms()
        age = first + exposure_ms - 1000.0 * epoch_s        # the epoch process refers to
        omega = self._rate_at(age, ticks)
        if omega is None and self.gyro is not None:
            try:
                omega = self.gyro()
            except Exception:
                omega = None
        if self.distrust:
            self.distrust -= 1
            omega = None
        prior = self.q
        p_time = self.q_time
        p_epoch = self.q_epoch_us
        guide = self.guide
        self.guide = None
        if prior is None and guide is not None:
            prior, p_time, p_epoch = guide
        dt = None
        if prior is not None:
            if p_epoch is not None and stamp is not None:
                d = (stamp - p_epoch) & _STAMP_MASK
                dt = d / 1e6 - (exposure_ms / 1000.0 - epoch_s) if d < _STAMP_HALF else None
            if dt is None:                                # integers: a float32 cannot hold ms
                dt = (now_ms - int(age + 0.5) - p_time) / 1000.0
        self.feed()
        self.last_result = None          # the last frame's result is not held through this one
        self.adopted = 0
        result = self.tracker.process(link.packet(n), prior=prior, omega=omega, dt=dt)
        self.feed()
        self.last_result = result
        status = self.last_status = result.status
        fused = False
        if result.q is not None and (status == S.OK or status == S.IMPRECISE):
            t_epoch = result.t_epoch_s if result.t_epoch_s is not None else epoch_s
            tag = now_ms - int(first + exposure_ms - 1000.0 * t_epoch + 0.5)   # its time tag
            before_us = int(1000.0 * (exposure_ms - 1000.0 * t_epoch) + 0.5)
            epoch = None if stamp is None else (stamp - before_us) & _STAMP_MASK
            fused = self._fuse(result, omega, epoch, tag)
        elif status == S.RATE_CONTRADICTED:
            self.fq = None                # the gyro that carries it is in doubt
        if status == S.OK or (fused and self._fused_precise()):
            if fused:
                self._adopt_fused(result)
            else:
                self.q = result.q
                self.adopted = 1
            if status == S.OK:
                _count(self.health, _H_OK)
            else:
                _count(self.health, _H_BAD)
            self.q_time = tag
            self.q_counter = counter
            self.q_stamp = stamp
            self._tops = top
            self._epoch(stamp, top, before_us)
            self.bad = 0
            self.level = LEVEL_NONE
            self._enter(TRACK)
            self._save_prior()
            if status == S.OK and result.min_sum != self.min_sum:
                self._write_min_sum(result.min_sum)
            return
        if status == S.RATE_CONTRADICTED:
            _count(self.health, _H_RATE_CONTRADICTED)
            self.distrust = DISTRUST_FRAMES
        self._bad_frame()
        if status == S.IMPRECISE and self.q is not None and 0 < result.min_sum < self.min_sum:
            self._write_min_sum(result.min_sum)     # too few stars: the tracker widens it
        if status == S.IMPRECISE and result.q is not None and self.q is None:
            self.guide = (self.fq if fused else result.q, tag, epoch)

    def _fuse(self, result, omega, epoch, tag):
        """Fold a verified frame's attitude into the fused estimate (:meth:`_combine`).
        Restarts from the frame without an estimate, a rate, a ``dt`` within
        ``fuse_gap_s``, or when an axis fails the gate (:data:`FUSE_GATE`).  False (the
        estimate dropped) for a frame without finite sigmas or a bad number; never raises."""
        try:
            rc = result.sigma_cross_arcsec
            rr = result.sigma_roll_arcsec
            rc = rc * rc
            rr = rr * rr
            if not (0.0 < rc < 1e12 and 0.0 < rr < 1e12):
                self.fq = None
                return False
            var = self.f_var
            dt = self._fuse_dt(epoch, tag) if omega is not None else None
            if dt is None or not self._combine(omega, result.q, var, dt, rc, rr):
                self.fq = result.q
                b = self.gyro_bias_rad_s * RAD_TO_ARCSEC
                var[0] = rc
                var[2] = rr
                var[1] = var[4] = b * b
                var[3] = var[5] = var[6] = 0.0
                drift = self.f_drift
                drift[0] = drift[1] = drift[2] = 0.0
                self.f_n = 1
            self.f_time = tag
            self.f_epoch = epoch
            return True
        except Exception:
            self.fq = None
            return False

    def _fuse_dt(self, epoch, tag):
        """Seconds from the fused attitude's time tag to a frame's (by the timestamps, else
        the spacecraft ms); None without an estimate or beyond ``fuse_gap_s``."""
        if self.fq is None:
            return None
        if epoch is not None and self.f_epoch is not None:
            d = (epoch - self.f_epoch) & _STAMP_MASK
            dt = d / 1e6 if d < _STAMP_HALF else None
        else:
            dt = (tag - self.f_time) / 1000.0
        if dt is None or not 0.0 <= dt <= self.fuse_gap_s:
            return None
        return dt

    def _combine(self, omega, q, var, dt, rc, rr):
        """``fq`` and ``var`` from ``fq`` carried ``dt`` s on the gyro's ``omega`` less the
        drift learnt (rad/s, camera frame: ``R(-omega dt)``, the prior's propagation,
        ``tracking.propagate``) and the frame's ``q`` (variances ``rc`` per cross axis,
        ``rr``): a Kalman filter of the carried attitude's error and its drift on the gyro
        (``f_drift``, the gyro's bias as the frames show it), the drift's variance starting
        at the declared bias squared and walking by :data:`GYRO_BIAS_WALK`.  About the
        boresight two states, the roll and its drift; across it the same in the x-y plane,
        isotropic (one variance per axis) and turned with the camera: a carried error
        turns by ``-omega_z dt`` each step while the drift, the gyro's, stays in the body,
        so their covariance is a complex number (``var[5]``, ``var[6]``).  False (nothing
        changed) when an axis fails the gate."""
        drift = self.f_drift
        dx = drift[0]
        dy = drift[1]
        dz = drift[2]
        p = multiply(from_rotation_vector(((dx / RAD_TO_ARCSEC - omega[0]) * dt,
                                           (dy / RAD_TO_ARCSEC - omega[1]) * dt,
                                           (dz / RAD_TO_ARCSEC - omega[2]) * dt)), self.fq)
        d = multiply(q, (-p[0], -p[1], -p[2], p[3]))      # q = d (x) p, camera frame
        s = 2.0 * RAD_TO_ARCSEC if d[3] >= 0.0 else -2.0 * RAD_TO_ARCSEC
        noise = self.gyro_noise_rad_s * dt * RAD_TO_ARCSEC
        noise = noise * noise
        walk = self.gyro_bias_walk * RAD_TO_ARCSEC
        walk = walk * walk * dt
        gate = self.fuse_gate
        e0 = s * d[0]
        e1 = s * d[1]
        e2 = s * d[2]
        turn = omega[2] * dt                              # the carried error turns by -turn
        cos = math.cos(turn)
        sin = math.sin(turn)
        cr = cos * var[5] + sin * var[6] + dt * var[1]    # the cross axes', carried dt
        ci = cos * var[6] - sin * var[5]
        v0 = var[0] + dt * (cos * var[5] + sin * var[6] + cr) + noise
        c2 = var[3] + dt * var[4]                         # the roll's
        v2 = var[2] + dt * (var[3] + c2) + noise
        if not (e0 * e0 <= gate * (v0 + rc) and e1 * e1 <= gate * (v0 + rc) and
                e2 * e2 <= gate * (v2 + rr)):
            return False
        s0 = v0 + rc
        s2 = v2 + rr
        g0 = v0 / s0 / RAD_TO_ARCSEC                      # the gains, rad per arcsec
        g2 = v2 / s2 / RAD_TO_ARCSEC
        fq = unit_quaternion(multiply(from_rotation_vector((g0 * e0, g0 * e1, g2 * e2)), p))
        if fq is None:
            return False
        self.fq = fq
        drift[0] = dx + (cr * e0 + ci * e1) / s0          # conj(c) e / s
        drift[1] = dy + (cr * e1 - ci * e0) / s0
        drift[2] = dz + c2 * e2 / s2
        var[0] = v0 * rc / s0
        var[1] = var[1] + walk - (cr * cr + ci * ci) / s0
        var[5] = cr * rc / s0
        var[6] = ci * rc / s0
        var[2] = v2 * rr / s2
        var[4] = var[4] + walk - c2 * c2 / s2
        var[3] = c2 * rr / s2
        self.f_n += 1
        return True

    def _fused_precise(self):
        """True when the fused attitude's total 5 sigma bound ``5 sqrt(2 sc^2 + sr^2)`` is
        within the tracker's ``max_error_arcsec`` (never without that setting)."""
        try:
            limit = self.tracker.settings.max_error_arcsec
            var = self.f_var
            return 25.0 * (2.0 * var[0] + var[2]) <= limit * limit
        except Exception:
            return False

    def _adopt_fused(self, result):
        """The fused attitude as the executive's (``q_sigma``: its sigmas); never looser than
        the frame alone (a fusion only shrinks the variances, a restart is the frame)."""
        var = self.f_var
        self.q = self.fq
        self.adopted = 2
        self.q_sigma[0] = var[0] ** 0.5
        self.q_sigma[1] = var[2] ** 0.5

    def _epoch(self, stamp, top, before_us):
        """``q_epoch_us``: ``before_us`` before the first pixel stamped ``stamp`` (low 30 bits,
        ``top`` the top 2), modulo 2**32 as a low 30 and a top 2 bits (``_tops``)."""
        if stamp is None:
            self.q_epoch_us = None
            return
        raw = stamp - before_us
        epoch = raw & _STAMP_MASK
        if raw < 0:
            top -= 1
        elif raw > _STAMP_MASK:
            top += 1
        self.q_epoch_us = epoch
        self._tops = (self._tops & 3) | (top & 3) << 2

    def _bad_frame(self):
        """A frame without an attitude: coast on the prior, then drop to lost in space with
        every record admitted again (and the fused estimate, which otherwise waits for the
        next verified frame within ``fuse_gap_s``)."""
        _count(self.health, _H_BAD)
        self.adopted = 0
        self.bad += 1
        if self.q is not None and self.bad <= self.coast_frames:
            _count(self.health, _H_COASTED)
            if self.state in (TRACK, COAST):
                self._enter(COAST)
            return
        if self.q is not None:
            _count(self.health, _H_LOST)
            self.q = self.fq = None
        if self.state in (TRACK, COAST):
            self._enter(ACQUIRE)
        if self.min_sum:
            self._write_min_sum(0)

    def _write_min_sum(self, value):
        code = self.link.write_reg("min_sum", value)
        if code == _link.OK:
            self.min_sum = value
        else:
            _count(self.health, _H_REG_FAULT)

    # ---- telemetry -----------------------------------------------------------------------

    def _emit(self):
        self.sequence = self.sequence + 1 if self.sequence < 0x3FFFFFFF else 0
        res = self.last_result
        q = self.q
        if q is None:
            q = _NO_Q
        sc = NAN
        sr = NAN
        matches = 0
        n_records = 0
        if res is not None:
            if res.sigma_cross_arcsec is not None:
                sc = res.sigma_cross_arcsec
            if res.sigma_roll_arcsec is not None:
                sr = res.sigma_roll_arcsec
            matches = min(255, len(res.matches))
            n_records = min(0xFFFF, res.n_records)
        if self.adopted == 2:               # the fused attitude's sigmas
            sc = self.q_sigma[0]
            sr = self.q_sigma[1]
        heap = self.heap_free
        if self.mem_free is not None and self.sequence % _HEAP_EVERY == 1:
            try:
                heap = self.heap_free = self.mem_free()
            except Exception:
                heap = 0
        h = self.health
        buf = self.record
        stamp = self.q_stamp or 0           # 32-bit stamps as 16-bit halves (PACK_FORMAT)
        epoch = self.q_epoch_us
        tops = self._tops if self.q_stamp is not None else 0
        e_hi = 0 if epoch is None else (tops >> 2) << 14 | epoch >> 16
        struct.pack_into(telemetry.PACK_FORMAT, buf, 0, telemetry.MAGIC, telemetry.VERSION,
                         self.state, self.sequence, max(0, self.q_time), self.q_counter or 0,
                         (tops & 3) << 14 | stamp >> 16, stamp & 0xFFFF, e_hi,
                         0 if epoch is None else epoch & 0xFFFF,
                         self.last_status & 0xFF, self.last_link & 0xFF, matches, self.level,
                         n_records, self.min_sum, q[0], q[1], q[2], q[3], sc, sr,
                         h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8], h[9], h[10],
                         h[11], h[12], h[13], h[14], h[15], h[16], h[17], h[18], h[19],
                         heap, 0)
        struct.pack_into(">I", buf, telemetry.BYTES - 4, crc32(self._record_body))
        if self.telemetry is not None:
            try:
                self.telemetry(buf)
            except Exception:
                pass

