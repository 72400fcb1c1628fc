"""The whole star tracker in the loop: the spacecraft on a trajectory, the MT9P031 register
model, frames rendered at the sensor's frame period with the settings the firmware wrote,
the gateware (Verilated board top or its golden model) and the unchanged flight executive
and link master on the MCU's peripherals, on one simulated clock.

    twin = Twin(cam, engine, trajectory, faults=["miso-flip"])
    rows = twin.run(30)                 # one row per executive step; twin.summary(rows)

The world's clock (``now``, s) moves when the MCU waits (``wait``: sleeps and IRQ polls) or
works (``spend``: SPI and two-wire wire time, the estimated F401 time of each ``process``,
:mod:`lodestar.fly.mcu`).  Before any pin is read or a transaction starts the world catches
up: every sensor frame whose read-out ended by ``now`` is rendered with the chip's
registers of that moment (exposure, gain, window, row time: :meth:`MT9P031.frame_settings`)
at the attitude of the start of its row 0's exposure (the firmware's epoch) and played into
the gateware, so the MCU's time per frame decides which frames it catches.  A frame whose
packet the golden engine would drop (its queue full) is counted but not rendered.  Faults:
:mod:`lodestar.fly.faults`.  Description and measurements: ``docs/fly.md``.
"""

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.firmware import executive, sensor
from lodestar.firmware import link as _link
from lodestar.firmware import status as S
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
from lodestar.fly import bus, faults, mcu, mpy
from lodestar.fly.mt9p031 import MT9P031
from lodestar.ground import onboard
from lodestar.ground.truth import attitude_error_arcsec
from lodestar.sim import catalogue, scene

_FRAMES = executive.HEALTH_NAMES.index("frames")
"""The executive's health counter of the frames read whole."""
WRONG_ARCSEC = 60.0
"""A reported attitude farther than this from the truth is wrong (issue 32)."""
WATCHDOG_MS = 2000
"""The twin's ``machine.WDT`` timeout (IWDG, ms): above the slowest lost-in-space frame's
gap between feeds."""
EXPOSURE_S = 0.1
FRAME_S = 0.1
"""The sensor's flight settings (``sensor.p031_flight``): 0.1 s exposure, 10 Hz."""


class World:
    """Clock, sensor chip, gateware engine, trajectory and the truth of every frame played."""

    def __init__(self, cam, engine, trajectory, seed=0, schedule=None):
        self.now = 0.0
        self.busy = 0.0
        self.cam = cam
        self.engine = engine
        self.trajectory = trajectory
        self.seed = seed
        self.schedule = schedule or faults.Schedule([])
        self.chip = MT9P031(lambda: self.now)
        self.next_start = 0.0
        self.frames = []               # truth of each frame played: dict
        self.counter_base = 0          # frames played before the gateware's counter restarted
        self.cat = catalogue.load()
        self.fault_log = []            # fault events of the current step
        self.hang = False              # the MCU is to hang in its next frame

    # ---- time ----------------------------------------------------------------------------

    def wait(self, seconds):
        self.now += seconds
        self.catch_up()

    def spend(self, seconds):
        self.now += seconds
        self.busy += seconds

    @property
    def frame_index(self):
        return len(self.frames)

    def active(self, name):
        return self.schedule.active(name, self.now)

    def count_fault(self, name):
        self.fault_log.append(name)

    # ---- frames --------------------------------------------------------------------------

    def catch_up(self):
        """Play every frame whose read-out ended by ``now``."""
        while True:
            s = self.chip.frame_settings()
            if s is None or self.active("sensor-silent"):
                if s is not None:
                    self.count_fault("sensor-silent")
                self.next_start = max(self.next_start, self.now)
                return
            start = self.next_start
            if start + s["window"][3] * s["row_s"] > self.now:
                return
            self.next_start = start + s["frame_s"]
            self._play(start, s)

    def _play(self, start, s):
        """Render frame ``index`` starting its read-out at ``start`` with settings ``s`` and
        play it into the gateware (a one-shot fault acting on it first)."""
        index = self.frame_index
        t0 = start - s["exposure_s"]
        q = self.trajectory.attitude(t0)
        truth = {"index": index, "t_s": start, "q": q,
                 "counter": (index - self.counter_base) & 0xFFFFFFFF}
        self.frames.append(truth)
        rows = None
        name = self.schedule.starting(start)
        if name == "watchdog":
            self.hang = True
        if name in ("truncated", "pll-loss"):
            rows = s["window"][3] // 2
            self.count_fault(name)
            if name == "pll-loss":
                self.engine.pll_loss()
        if name == "soft-reset":
            self.count_fault(name)
            self.engine.cs(0)
            self.engine.xfer(C.keyed_command(C.OP_SOFT_RESET))
            self.engine.cs(1)
            self.counter_base = index              # this frame is the first after it
            truth["counter"] = 0
        if not self.engine.accepts():
            self.engine.skip()
            return
        omega = np.degrees(self.trajectory.omega(t0))
        cam = dataclasses.replace(self.cam, row_time_s=s["row_s"],
                                  gain_adu_per_e=self.cam.gain_adu_per_e * s["gain"])
        sim = scene.simulate(cam, q, omega, s["exposure_s"], seed=self.seed * 100003 + index,
                             cat=self.cat)
        w, h = s["window"][2:]
        frame = np.zeros((h, w), dtype=np.uint16)
        frame[:min(h, cam.height), :min(w, cam.width)] = sim.frame[:h, :w]
        self.engine.frame(frame, rows, start_us=round(start * 1e6))

    def soft_reset(self):
        """The gateware's frame counter restarts: the next frame played is counter 0."""
        self.counter_base = self.frame_index

    def truth_of(self, counter):
        """The truth of the latest frame played with gateware frame counter ``counter``."""
        for truth in reversed(self.frames):
            if truth["counter"] == counter:
                return truth
        return None


class Store:
    """The persistent store of the prior (RTC backup registers): survives an MCU reset."""

    def __init__(self):
        self.data = None

    def read(self):
        return self.data

    def write(self, data):
        self.data = bytes(data)


def make_engine(name, cam, log=None):
    """The gateware engine ``name`` (``golden`` or ``verilator``) for ``cam``'s frame with
    the estcube2 board's capacities (the board's own top at its frame); ``log(text)`` hears
    of a Verilator build."""
    from lodestar.hdl.boards import BOARDS, GatewareTop

    board = BOARDS["estcube2"]
    if (cam.width, cam.height) == (board.width, board.height):
        top = board.gateware_top()
    else:
        top = GatewareTop("mt9p031", cam.width, cam.height,
                          record_capacity=board.record_capacity, record_depth=board.record_depth)
    if name == "golden":
        from lodestar.fly.golden_top import GoldenTop

        return GoldenTop(cam.width, cam.height, cam.pixel_bits, top.detector.record_capacity,
                         top.detector.label_capacity, top.build)
    from lodestar.fly.verilated import VerilatedTop

    return VerilatedTop(top, log=log)


def flight_settings(cam, exposure_s=EXPOSURE_S, frame_s=FRAME_S):
    """``(sensor settings, detector registers)`` of the flight loop for ``cam``: the
    MT9P031 settings of a ``frame_s`` period and ``exposure_s`` for the camera's window
    (``sensor.p031_flight``; a window too small for the period at the longest vertical
    blanking gets a longer row, horizontal blanking, instead) and the preset's tuned
    fixed-threshold registers (``ground.onboard``)."""
    window = (16, 54, cam.width, cam.height)
    st, reason, settings = sensor.p031_flight(exposure_s, frame_s, window=window)
    if st != S.OK:
        raise ValueError(reason)
    pix = sensor.p031_pll(sensor.EXTCLK_HZ, sensor.PIXCLK_HZ)[3]
    rows = cam.height + settings["vblank"]
    units = int(math.ceil(frame_s * pix / 2 / rows))
    if settings["vblank"] >= 4096 and units > cam.width // 2 + settings["hblank"]:
        settings["hblank"] = units - cam.width // 2
        so = 2.0 * (sensor.P031_SO_BASE + 1) / pix
        settings["exposure"] = int((exposure_s + so) / (2.0 * units / pix) + 0.5)
    chosen = onboard.camera_settings(cam.name)
    cfg = onboard.detector_config(cam, chosen, exposure_s)
    return settings, cfg.registers()


class Twin:
    """The loop (module docstring).  ``cam``: a ``lodestar.sim`` camera whose frame is the
    gateware's; ``engine``: a ``VerilatedTop`` or ``GoldenTop``; ``trajectory``,
    ``gyro``: :mod:`lodestar.fly.trajectory`; ``faults``: scenario names
    (:data:`lodestar.fly.faults.SCENARIOS`) started at ``fault_frame``; ``wrong_arcsec``:
    the error beyond which a reported attitude is wrong."""

    def __init__(self, cam, engine, trajectory, gyro, faults_=(), fault_frame=20, seed=0,
                 database=None, capacity=C.FLIGHT_RECORD_CAPACITY, wrong_arcsec=WRONG_ARCSEC,
                 micropython=None):
        self.schedule = faults.Schedule(faults_, fault_frame)
        self.world = World(cam, engine, trajectory, seed, self.schedule)
        self.gyro = gyro
        self.capacity = capacity
        self.fw_cam = onboard.firmware_camera(cam)
        self.database, self.db_path = database, None
        if database is None:
            self.database, self.db_path = onboard.star_database(self.fw_cam, label=cam.name)
        self.sensor_settings, self.registers = flight_settings(cam)
        self.store = Store()
        self.reboots = 0
        self.wrong_arcsec = wrong_arcsec
        self.micropython = micropython
        self.exe_dir = tempfile.TemporaryDirectory(prefix="lodestar-fly-")
        self.exe = None
        self._boot()

    def _tracker(self, slot=0):
        db = self.database
        if slot == 0 and self.schedule.has("db-crc"):
            if self.db_path is None:
                raise ValueError("--faults db-crc needs the star database's cache file")
            db = faults.corrupt(self.db_path)
        settings = Settings(method="pyramid", exposure_s=EXPOSURE_S,
                            row_time_s=self.world.cam.row_time_s,
                            tolerance_px=onboard.default_tolerance_px(self.fw_cam))
        return mcu.TimedTracker(StarTracker(db, self.fw_cam, settings),
                                lambda ms: self.world.spend(ms / 1000.0))

    def _boot(self):
        """Power-up or watchdog reset of the MCU: new peripherals, link and executive (on
        CPython here, or a new MicroPython process: ``micropython``, its binary); the store
        (the prior), the gateware and the sensor keep their state."""
        w = self.world
        self.clock = bus.Clock(w)
        self.spi = bus.Spi(w)
        self.i2c = bus.I2c(w)
        self.watchdog = bus.Watchdog(w, WATCHDOG_MS)
        if self.micropython is not None:
            if self.exe is not None:
                self.exe.close()
            self.exe = mpy.Remote(self.micropython, self._mcu_config(), self._serve)
            self.link = self.exe.link
            return
        self.link = _link.Link(self.spi, self.spi.cs, self.spi.irq, self.clock,
                               capacity=self.capacity)
        cam = sensor.Sensor(self.i2c, sensor.MT9P031, sleep_ms=self.clock.sleep_ms)
        self.exe = executive.Executive(
            self.link, self._tracker(), self.clock, sensor=cam,
            sensor_settings=dict(self.sensor_settings), registers=dict(self.registers),
            watchdog=self.watchdog, store=self.store, gyro=lambda: self.gyro.measure(w.now),
            now_ms=lambda: int(w.now * 1000), select_database=self._tracker,
            frame_s=FRAME_S)

    def _mcu_config(self):
        """What the MicroPython MCU builds its executive from (``mpy.MCU_SCRIPT``)."""
        if self.db_path is None:
            raise ValueError("--mcu micropython needs the star database's cache file")
        slot0 = str(self.db_path)
        if self.schedule.has("db-crc"):
            slot0 = str(Path(self.exe_dir.name) / "slot0.lsdb")
            Path(slot0).write_bytes(faults.corrupt(self.db_path))
        return {"databases": [slot0, str(self.db_path)], "camera": self.fw_cam.as_dict(),
                "exposure_s": EXPOSURE_S, "row_time_s": self.world.cam.row_time_s,
                "tolerance_px": onboard.default_tolerance_px(self.fw_cam),
                "capacity": self.capacity, "sensor_settings": dict(self.sensor_settings),
                "registers": dict(self.registers), "frame_s": FRAME_S}

    def _serve(self, remote, line):
        """The answer to one request of the MicroPython MCU (``mpy.MCU_SCRIPT``)."""
        op, _, rest = line.partition(" ")
        w = self.world
        if op == "x":
            data = bytes.fromhex(rest)
            into = bytearray(len(data))
            self.spi.write_readinto(data, into)
            return into.hex()
        if op in ("w", "r"):
            addr, reg, arg = rest.split()
            try:
                if op == "w":
                    self.i2c.writeto_mem(int(addr), int(reg), bytes.fromhex(arg))
                    return ""
                return bytes(self.i2c.readfrom_mem(int(addr), int(reg), int(arg))).hex()
            except OSError:
                return "E"
        if op == "p":
            n, prior, moving = rest.split()
            w.spend(remote.process_ms(int(n), prior == "1", float(moving)) / 1000.0)
            return ""
        simple = {"t": lambda: self.clock.ticks_ms(), "i": lambda: self.spi.irq.value(),
                  "f": self.watchdog.feed, "n": lambda: int(w.now * 1000),
                  "g": lambda: " ".join(repr(v) for v in self.gyro.measure(w.now)),
                  "sr": lambda: "-" if self.store.data is None else self.store.data.hex(),
                  "s": lambda: self.clock.sleep_ms(int(rest)),
                  "c": lambda: self.spi.cs.value(int(rest)),
                  "sw": lambda: self.store.write(bytes.fromhex(rest))}
        got = simple[op]()
        return "" if got is None else str(got)

    def step(self):
        """One executive step: its row (telemetry and truth)."""
        w = self.world
        exe = self.exe
        frames_before = exe.health[_FRAMES]
        busy0 = w.busy
        w.fault_log = []
        self.schedule.ground(self, w.now)
        if w.hang:
            w.hang = False
            w.count_fault("watchdog")
            (exe if self.micropython is not None else exe.tracker).hang_ms = faults.HANG_MS
        exe.step()
        row = {"index": 0, "t_s": round(w.now, 6), "status": "NO_FRAME",
               "mode": executive.STATE_NAMES[exe.state], "error_arcsec": None,
               "mcu_ms": round((w.busy - busy0) * 1000, 3), "records": 0, "faults": [],
               "frame": None, "solve": None, "level": exe.level, "wrong": False,
               "reported": None, "reported_error_arcsec": None, "sigma_cross_arcsec": None,
               "sigma_roll_arcsec": None, "beyond_5sigma": False, "beyond_180": False}
        if exe.health[_FRAMES] != frames_before:
            self._judge(row, exe.last_result)
            self._judge_reported(row)
        elif exe.last_link != _link.OK:
            row["status"] = _link.CODE_NAMES[exe.last_link]
        if self.watchdog.check():
            w.count_fault("watchdog-reset")
            self.reboots += 1
            self._boot()
        row["faults"] = sorted(set(w.fault_log))
        return row

    def _judge(self, row, result):
        truth = self.world.truth_of(self.link.last_frame_counter)
        row["status"] = S.name(result.status)
        row["records"] = result.n_records
        row["solve"] = result.mode
        row["frame"] = truth["index"] if truth else None
        if result.status == S.OK and result.q is not None and truth is not None:
            err = attitude_error_arcsec(result.q, truth["q"])["total"]
            row["error_arcsec"] = round(err, 3)
            row["wrong"] = err > self.wrong_arcsec

    def _judge_reported(self, row):
        """The attitude the executive adopted at this frame (``reported``: ``frame``, its own,
        or ``fused``, through the gyro), judged at its time tag, the frame's epoch: its error
        (x, y, roll and total, arcsec), the sigmas it reports, and whether it is wrong by
        issue 33's definition (the truth beyond 5 sigma on an axis, ``beyond_5sigma``, or
        beyond 180", ``beyond_180``) and by the twin's (> ``wrong_arcsec``, ``wrong``)."""
        exe = self.exe
        adopted = getattr(exe, "adopted", 0)
        truth = self.world.truth_of(self.link.last_frame_counter)
        if not adopted or exe.q is None or truth is None:
            return
        result = exe.last_result
        sc, sr = (exe.q_sigma[0], exe.q_sigma[1]) if adopted == 2 else \
            (result.sigma_cross_arcsec, result.sigma_roll_arcsec)
        err = attitude_error_arcsec(list(exe.q), truth["q"])
        row["reported"] = "fused" if adopted == 2 else "frame"
        row["reported_error_arcsec"] = {k: round(err[k], 3) for k in ("x", "y", "roll", "total")}
        row["sigma_cross_arcsec"] = None if sc is None else round(float(sc), 3)
        row["sigma_roll_arcsec"] = None if sr is None else round(float(sr), 3)
        row["beyond_5sigma"] = sc is None or sr is None or not (
            abs(err["x"]) <= 5 * sc and abs(err["y"]) <= 5 * sc and abs(err["roll"]) <= 5 * sr)
        row["beyond_180"] = err["total"] > 180.0
        row["wrong"] = row["wrong"] or err["total"] > self.wrong_arcsec

    def close(self):
        """End the MicroPython MCU's process, if any, and remove the run's files."""
        if self.micropython is not None and self.exe is not None:
            self.exe.close()
        self.exe_dir.cleanup()

    def run(self, n_frames, progress=None):
        """Step until ``n_frames`` sensor frames were played (at most 20 steps a frame):
        the rows, ``index`` numbered from 0.  ``progress(frames)`` after each step."""
        rows = []
        limit = 20 * n_frames + 50
        while self.world.frame_index < n_frames and len(rows) < limit:
            row = self.step()
            row["index"] = len(rows)
            rows.append(row)
            if progress is not None:
                progress(min(self.world.frame_index, n_frames))
        return rows


def summary(rows, twin):
    """Figures of a run: steps, frames played, solved, wrong, the first solve, availability
    after it (solved steps over frame steps), the errors, per-fault recovery."""
    solved = [r for r in rows if r["status"] == "OK"]
    errors = [r["error_arcsec"] for r in solved if r["error_arcsec"] is not None]
    first = solved[0]["index"] if solved else None
    after = [r for r in rows[first:] if r["frame"] is not None or r["status"] != "NO_FRAME"] \
        if first is not None else []
    exe = twin.exe
    return {
        "steps": len(rows), "frames_played": twin.world.frame_index,
        "solved": len(solved), "wrong": sum(r["wrong"] for r in rows),
        "first_solve_step": first,
        "first_solve_t_s": rows[first]["t_s"] if first is not None else None,
        "availability_after_first": (sum(r["status"] == "OK" for r in after) / len(after)
                                     if after else 0.0),
        "tracking_solves": sum(r["solve"] == "tracking" for r in solved),
        "lost_in_space_solves": sum(r["solve"] == "lost_in_space" for r in solved),
        "max_error_arcsec": max(errors) if errors else None,
        **_reported(rows),
        "rms_error_arcsec": math.sqrt(sum(e * e for e in errors) / len(errors))
        if errors else None,
        "recovery": faults.recovery(rows, twin.schedule),
        "health": {name: exe.health[i] for i, name in enumerate(executive.HEALTH_NAMES)},
        "link": {name: twin.link.counters[i] for i, name in enumerate(_link.COUNTER_NAMES)},
        "reboots": twin.reboots, "watchdog_max_gap_ms": round(twin.watchdog.max_gap_ms, 1),
        "mcu_ms_mean": sum(r["mcu_ms"] for r in rows) / len(rows) if rows else 0.0,
    }


def _reported(rows):
    """The attitudes the executive reported (its own or fused, ``Twin._judge_reported``):
    how many, how many fused, their availability after the first (over the steps that read
    or waited for a frame), the largest error and how many are wrong by issue 33's
    definition (beyond 5 sigma on an axis, or beyond 180")."""
    rep = [r for r in rows if r["reported"] is not None]
    first = rep[0]["index"] if rep else None
    after = [r for r in rows[first:] if r["frame"] is not None or r["status"] != "NO_FRAME"] \
        if first is not None else []
    return {"reported": len(rep), "reported_fused": sum(r["reported"] == "fused" for r in rep),
            "reported_availability_after_first": (sum(r["reported"] is not None for r in after)
                                                  / len(after) if after else 0.0),
            "reported_max_error_arcsec": max((r["reported_error_arcsec"]["total"] for r in rep),
                                             default=None),
            "reported_beyond_5sigma": sum(r["beyond_5sigma"] for r in rep),
            "reported_beyond_180": sum(r["beyond_180"] for r in rep)}
