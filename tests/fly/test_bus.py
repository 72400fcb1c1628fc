"""The MCU's peripherals on the twin's clock: wire time spent, the world caught up before a
transaction, the watchdog's gaps, the faults on MISO, MOSI and IRQ, the detector's soft
reset seen on MOSI."""

import pytest

from lodestar import contract as C
from lodestar.fly import bus


class _Engine:
    def __init__(self):
        self.sent, self.level = [], 1

    def irq(self):
        return True

    def cs(self, level):
        self.level = level

    def xfer(self, data):
        self.sent.append(bytes(data))
        return bytearray(range(len(data)))


class _World:
    def __init__(self, faults=()):
        self.now, self.busy, self.faults = 0.0, 0.0, set(faults)
        self.engine, self.caught, self.counted, self.resets = _Engine(), 0, [], 0

    def wait(self, s):
        self.now += s

    def spend(self, s):
        self.now += s
        self.busy += s

    def catch_up(self):
        self.caught += 1

    def active(self, name):
        return name in self.faults

    def count_fault(self, name):
        self.counted.append(name)

    def soft_reset(self):
        self.resets += 1


def test_spi_spends_wire_time_and_catches_up_first():
    w = _World()
    spi = bus.Spi(w)
    spi.cs.value(0)
    into = bytearray(100)
    spi.readinto(into)
    spi.cs.value(1)
    assert w.caught == 1 and w.engine.level == 1 and into[99] == 99
    assert w.busy == pytest.approx(800 / 10.5e6)
    assert spi.irq.value() == 1 and w.caught == 2


def test_faults_on_the_wires():
    w = _World({"mosi-flip", "miso-flip", "irq-stuck-low"})
    spi = bus.Spi(w)
    spi.cs.value(0)
    spi.write(bytes((C.OP_READ_STATUS, 0)))
    into = bytearray(64)
    spi.readinto(into)
    spi.cs.value(1)
    assert w.engine.sent[0][0] == C.OP_READ_STATUS ^ 1 and into[40] == 40 ^ 0x10
    assert spi.irq.value() == 0 and w.counted == ["mosi-flip", "miso-flip", "irq-stuck-low"]
    w.faults = {"irq-stuck-high"}
    assert spi.irq.value() == 1


def test_soft_reset_seen_and_watchdog():
    w = _World()
    spi = bus.Spi(w)
    spi.cs.value(0)
    spi.write(C.keyed_command(C.OP_SOFT_RESET))
    spi.cs.value(1)
    assert w.resets == 1
    wdt = bus.Watchdog(w, 2000)
    w.now += 1.5
    wdt.feed()
    assert not wdt.check()
    w.now += 2.5
    assert wdt.check() and wdt.expired
    clock = bus.Clock(w)
    clock.sleep_ms(20)
    assert clock.ticks_ms() == 4020 and clock.ticks_diff(5, 3) == 2
