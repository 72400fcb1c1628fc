"""Named fault scenarios of the twin, when they act and how the run recovered from each.

A scenario starts at a nominal time (``fault_frame`` x 0.1 s, default 2 s, when the loop
tracks at the frame rate; then every ``SPACING`` frames for the next one) and lasts its
:data:`SCENARIOS` number of sensor periods (0.1 s each) of the twin's clock; a one-shot
scenario acts on the first frame played from its start.

- ``miso-flip``: one bit flipped inside every packet read on MISO (CRC-32 refuses it; the
  link resynchronises).
- ``mosi-flip``: the opcode's low bit flipped on MOSI in every transaction (a status read
  becomes a stream read, a register write an unknown opcode; read-back and CRC-8 refuse).
- ``irq-stuck-high``, ``irq-stuck-low``: the IRQ line stuck.
- ``pll-loss``: the board's PLL loses lock mid-frame (the frame stops half way; the status
  word's ``OVF_CLOCK_LOST`` rises; the executive starts the sensor again).
- ``truncated``: a frame ends half way (FRAME_VALID falls early).
- ``soft-reset``: the detector datapath is reset mid-run (its frame counter restarts).
- ``sensor-silent``: the sensor stops answering on the two-wire bus and streaming.
- ``db-crc``: the star database in slot 0 fails its CRC at boot; the ground selects slot 1.
- ``watchdog``: the MCU hangs for :data:`HANG_MS` inside a frame without feeding the
  watchdog, which resets it (the prior and the database slot survive in the store).

The ground's part (:meth:`Schedule.ground`): a tracker that stays in ``SAFE`` for
:data:`SAFE_GROUND_S` gets a command to start again (the database slot 1 first when the
database was the reason), as an operator would.
"""

from pathlib import Path

from lodestar.firmware import executive

SCENARIOS = {"miso-flip": 3, "mosi-flip": 3, "irq-stuck-high": 3, "irq-stuck-low": 4,
             "pll-loss": 1, "truncated": 1, "soft-reset": 1, "sensor-silent": 3,
             "db-crc": 0, "watchdog": 1}
"""Scenario name -> sensor periods it lasts (0: from boot, one-shots 1).  The IRQ line stuck
low lasts longer than the executive's 250 ms wait plus a period, so that a wait begun inside
it times out whatever the phase of the loop's steps (at 3 periods it did or not by the step's
length: with the step measured with the real link it never did)."""
ONE_SHOT = ("pll-loss", "truncated", "soft-reset", "watchdog")
PERIOD_S = 0.1
SPACING = 15
"""Sensor periods between the starts of two scenarios of one run."""
HANG_MS = 2500
"""The ``watchdog`` scenario's hang (ms), beyond the twin's 2 s watchdog."""
SAFE_GROUND_S = 1.0
RECOVERY_FRAMES = {"miso-flip": 3, "mosi-flip": 3, "irq-stuck-high": 3, "irq-stuck-low": 3,
                   "pll-loss": 6, "truncated": 3, "soft-reset": 3, "sensor-silent": 3,
                   "db-crc": 25, "watchdog": 6}
"""Sensor periods from a fault's end to the next tracking solve that ``docs/fly.md``
states for each scenario, from the executive's design: a refused packet or frame costs
itself and a resync, and a burst of link errors one attempt per frame (coasted over), so
tracking is back within the packets queued meanwhile (3); a clock loss restarts the sensor
(6); a fault that reaches ``SAFE`` waits for the ground's command (1 s), a configuration
and a lost-in-space solve (``db-crc``: from boot, 25); a watchdog reset runs boot and
configuration and tracks from the stored prior after the frames that queued during the
hang (6, from the step that hung)."""


def check(names):
    """``names`` if every one is a scenario, else ``ValueError`` naming the first that is
    not."""
    for name in names:
        if name not in SCENARIOS:
            raise ValueError(f"--faults {name!r} is not one of {', '.join(SCENARIOS)}")
    return list(names)


class Schedule:
    """When each scenario of ``names`` acts (module docstring)."""

    def __init__(self, names, fault_frame=20):
        self.names = check(names)
        self.windows = {}
        k = 0
        for name in self.names:
            if name == "db-crc":
                self.windows[name] = (0.0, 0.0)
                continue
            start = (fault_frame + SPACING * k) * PERIOD_S
            self.windows[name] = (start, start + SCENARIOS[name] * PERIOD_S)
            k += 1
        self.fired = set()
        self._safe_since = None

    def has(self, name):
        return name in self.windows

    def active(self, name, now):
        w = self.windows.get(name)
        return w is not None and w[0] <= now < w[1] and name not in ONE_SHOT

    def starting(self, now):
        """The one-shot scenario that acts on a frame played at ``now``, once, or None."""
        for name in self.names:
            if name in ONE_SHOT and name not in self.fired and self.windows[name][0] <= now:
                self.fired.add(name)
                return name
        return None

    def ground(self, twin, now):
        """Before each step: the hang of ``watchdog`` and the ground's commands."""
        exe = twin.exe
        if exe.state != executive.SAFE:
            self._safe_since = None
            return
        if self._safe_since is None:
            self._safe_since = now
            return
        if now - self._safe_since >= SAFE_GROUND_S:
            if exe.reason.startswith("database"):
                exe.command(executive.CMD_DATABASE, 1)
            exe.command(executive.CMD_MODE, executive.MODE_AUTO)
            self._safe_since = None


def corrupt(path):
    """The star database at ``path`` with one byte of its payload flipped (its CRC fails)."""
    data = bytearray(Path(path).read_bytes())
    data[len(data) // 2] ^= 0x01
    return bytes(data)


def recovery(rows, schedule):
    """Per scenario: ``{"start_s", "end_s", "recovered_s", "frames_to_recovery",
    "stated", "within"}``: the first solve in ``TRACK`` after the fault's end, in sensor
    periods after it.  The end is the window's, or the last step the fault acted in if
    later (a one-shot acts on a step after its start: the ``watchdog`` hang ends with the
    step that hung)."""
    out = {}
    for name, (start, end) in schedule.windows.items():
        last = max((i for i, r in enumerate(rows) if name in r["faults"]), default=-1)
        if last >= 0:
            end = max(end, rows[last]["t_s"])
        back = next((r for r in rows[last + 1:] if r["t_s"] >= end and r["status"] == "OK"
                     and r["mode"] == "TRACK"), None)
        frames = None if back is None else max(0, int((back["t_s"] - end) / PERIOD_S + 0.999))
        out[name] = {"start_s": start, "end_s": end,
                     "recovered_s": None if back is None else back["t_s"],
                     "frames_to_recovery": frames, "stated": RECOVERY_FRAMES[name],
                     "within": frames is not None and frames <= RECOVERY_FRAMES[name]}
    return out
