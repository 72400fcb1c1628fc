"""``--mcu micropython``: the unchanged executive, link master, sensor driver and pipeline on
the flight MCU's MicroPython (the 32-bit unix port with float32 in the object word and the
firmware frozen, :func:`lodestar.regress.unixport.float32_build`), its peripherals served by
the twin over the process's stdin and stdout, one request a line.

The MCU side (:data:`MCU_SCRIPT`) makes ``time``, ``machine.SPI`` with its CS and IRQ pins,
``machine.I2C``, ``machine.WDT``, the prior's store and the gyro as objects whose every call
is a request (``t`` ticks, ``s N`` sleep, ``i`` IRQ, ``c V`` CS, ``x HEX`` SPI bytes, ``w``
and ``r`` two-wire accesses, ``f`` feed, ``g`` gyro, ``n`` time tag, ``sr``/``sw`` store,
``p RECORDS PRIOR MOVING`` a ``process`` done); the twin answers each on the same clock as
the CPython MCU's (:class:`Remote`).  The twin sends ``q CODE ARG`` to queue a command and
``step`` for one executive step, answered by ``D`` and the step's figures as JSON.
"""

import json
import subprocess
import tempfile
from pathlib import Path

from lodestar.firmware import executive
from lodestar.fly import mcu

HEAPSIZE = 4 << 20
"""The unix port's heap for the twin: the flight heap budget is measured on its own
(``docs/mcu_board.md``); here a missing megabyte must not end the run."""

MCU_SCRIPT = r'''
import sys, json
from binascii import hexlify, unhexlify
from lodestar.firmware import executive, sensor
from lodestar.firmware import link as _link
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings

def ask(line):
    sys.stdout.write(line + "\n")
    return sys.stdin.readline().strip()

class Clock:
    def ticks_ms(self):
        return int(ask("t"))
    def ticks_diff(self, a, b):
        return a - b
    def sleep_ms(self, n):
        ask("s %d" % n)

class Pin:
    def __init__(self, kind):
        self.kind = kind
    def value(self, v=None):
        if v is None:
            return int(ask("i"))
        ask("c %d" % v)

class Spi:
    def write_readinto(self, out, into):
        got = unhexlify(ask("x " + hexlify(bytes(out)).decode()))
        for k in range(len(got)):
            into[k] = got[k]
    def write(self, out):
        self.write_readinto(out, bytearray(len(out)))
    def readinto(self, into, write=0):
        self.write_readinto(bytes((write,)) * len(into), into)

class I2c:
    def writeto_mem(self, addr, reg, buf):
        if ask("w %d %d %s" % (addr, reg, hexlify(bytes(buf)).decode())) == "E":
            raise OSError(19)
    def readfrom_mem(self, addr, reg, n):
        r = ask("r %d %d %d" % (addr, reg, n))
        if r == "E":
            raise OSError(19)
        return unhexlify(r)

class Wdt:
    def feed(self):
        ask("f")

class Store:
    def read(self):
        r = ask("sr")
        return None if r == "-" else unhexlify(r)
    def write(self, data):
        ask("sw " + hexlify(bytes(data)).decode())

class Timed:
    def __init__(self, tracker):
        self.tracker = tracker
        self.settings = tracker.settings
        self.status = tracker.status
        self.reason = tracker.reason
    def prefetch(self, prior=None, omega=None, dt=None):
        return self.tracker.prefetch(prior, omega, dt)
    def process(self, packet, prior=None, omega=None, dt=None):
        res = self.tracker.process(packet, prior=prior, omega=omega, dt=dt)
        moving = 0 if omega is None else sum([w * w for w in omega])
        ask("p %d %d %r" % (res.n_records, prior is not None, moving))
        return res

def gyro():
    return tuple(float(v) for v in ask("g").split())

cfg = json.load(open(sys.argv[1]))
if "window" in cfg["sensor_settings"]:
    cfg["sensor_settings"]["window"] = tuple(cfg["sensor_settings"]["window"])

def tracker(slot=0):
    s = Settings(method="pyramid", exposure_s=cfg["exposure_s"], row_time_s=cfg["row_time_s"],
                 tolerance_px=cfg["tolerance_px"])
    return Timed(StarTracker(cfg["databases"][min(slot, 1)], cfg["camera"], s))

clock = Clock()
spi = Spi()
link = _link.Link(spi, Pin("cs"), Pin("irq"), clock, capacity=cfg["capacity"])
cam = sensor.Sensor(I2c(), sensor.MT9P031, sleep_ms=clock.sleep_ms)
exe = executive.Executive(link, tracker(), clock, sensor=cam,
                          sensor_settings=cfg["sensor_settings"], registers=cfg["registers"],
                          watchdog=Wdt(), store=Store(), gyro=gyro,
                          now_ms=lambda: int(ask("n")), select_database=tracker,
                          frame_s=cfg["frame_s"])
while True:
    line = sys.stdin.readline().strip()
    if not line:
        break
    if line.startswith("q "):
        code, arg = line.split()[1:]
        exe.command(int(code), int(arg))
        continue
    exe.step()
    r = exe.last_result
    out = {"state": exe.state, "level": exe.level, "last_link": exe.last_link,
           "reason": exe.reason, "health": list(exe.health), "min_sum": exe.min_sum,
           "counters": list(link.counters), "counter": link.last_frame_counter,
           "status": None if r is None else r.status,
           "n_records": 0 if r is None else r.n_records,
           "mode": None if r is None else r.mode,
           "q": None if (r is None or r.q is None) else list(r.q),
           "sigmas": None if r is None else [r.sigma_cross_arcsec, r.sigma_roll_arcsec],
           "adopted": exe.adopted, "exe_q": None if exe.q is None else list(exe.q),
           "q_sigma": list(exe.q_sigma) if exe.adopted == 2 else None}
    sys.stdout.write("D " + json.dumps(out) + "\n")
'''


class _Result:
    def __init__(self, d):
        self.status, self.n_records, self.mode, self.q = (d["status"], d["n_records"],
                                                          d["mode"], d["q"])
        self.sigma_cross_arcsec, self.sigma_roll_arcsec = d.get("sigmas") or (None, None)


class _Link:
    def __init__(self):
        self.counters = [0] * 16
        self.last_frame_counter = None


class Remote:
    """The executive on MicroPython, seen from the twin with the attributes
    :class:`lodestar.fly.twin.Twin` reads of a local one (``state``, ``level``,
    ``last_link``, ``reason``, ``health``, ``min_sum``, ``last_result``, the attitude it
    reported: ``adopted``, ``q``, ``q_sigma``; ``link`` its
    counters and last frame counter), and ``command`` queued for the next step."""

    def __init__(self, binary, config, serve):
        self.serve = serve
        self.tmp = tempfile.TemporaryDirectory(prefix="lodestar-fly-")
        script = Path(self.tmp.name) / "mcu.py"
        script.write_text(MCU_SCRIPT)
        conf = Path(self.tmp.name) / "config.json"
        conf.write_text(json.dumps(config))
        self.proc = subprocess.Popen([str(binary), "-X", f"heapsize={HEAPSIZE}", str(script),
                                      str(conf)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, bufsize=1)
        self.state, self.level, self.last_link, self.reason = executive.BOOT, 0, 0, ""
        self.health = [0] * executive.N_HEALTH
        self.min_sum = 0
        self.last_result = None
        self.adopted, self.q, self.q_sigma = 0, None, [None, None]
        self.link = _Link()
        self.hang_ms = 0

    def command(self, code, arg=None, value=None):
        self.proc.stdin.write(f"q {code} {arg}\n")
        return True

    def step(self):
        """One executive step, serving its requests until it reports."""
        self.proc.stdin.write("step\n")
        while True:
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError("the MicroPython MCU stopped")
            line = line.rstrip("\n")
            if line.startswith("D "):
                break
            self.proc.stdin.write(self.serve(self, line) + "\n")
        d = json.loads(line[2:])
        self.state, self.level, self.last_link, self.reason = (d["state"], d["level"],
                                                               d["last_link"], d["reason"])
        self.health, self.min_sum = d["health"], d["min_sum"]
        self.link.counters, self.link.last_frame_counter = d["counters"], d["counter"]
        self.last_result = _Result(d) if d["status"] is not None else None
        self.adopted, self.q = d["adopted"], d["exe_q"]
        self.q_sigma = d["q_sigma"] or [None, None]
        return self.state

    def process_ms(self, n_records, prior, moving):
        """The MCU time of a ``process`` the MCU reported (and a pending hang, once)."""
        res = _Result({"status": 0, "n_records": n_records, "mode": None, "q": None})
        ms = mcu.process_ms(res, (0, 0, 0, 1) if prior else None,
                            (moving ** 0.5, 0.0, 0.0)) + mcu.LOOP_MS + self.hang_ms
        self.hang_ms = 0
        return ms

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.close()
            self.proc.kill()
            self.proc.wait()
        self.tmp.cleanup()
