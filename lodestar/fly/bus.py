"""The MCU's peripherals in the twin, the objects the unchanged firmware takes: ``time``
(``ticks_ms``, ``ticks_diff``, ``sleep_ms``), ``machine.SPI`` with its CS and IRQ ``Pin``s,
``machine.I2C`` to the sensor, ``machine.WDT``.  Each call moves the twin's clock by what it
costs on the board (SPI bytes at 10.5 MHz, two-wire accesses at 400 kHz) and lets the world
(sensor frames into the gateware) catch up first, so the gateware answers what it would have
at that instant.  Faults act here: bits flipped on MISO or MOSI, the IRQ line stuck.
"""

from lodestar import contract as C

I2C_HZ = 400000
"""The sensor's two-wire clock (fast mode)."""
I2C_BITS = 9 * 4
"""Bits of one register access on the wire (address, register, two data bytes, ACKs)."""
_SOFT_RESET = C.keyed_command(C.OP_SOFT_RESET)


class Clock:
    """MicroPython's ``time`` on the twin's clock (integer ms ticks)."""

    def __init__(self, world):
        self.world = world

    def ticks_ms(self):
        return int(self.world.now * 1000)

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, n):
        self.world.wait(n / 1000.0)


class Watchdog:
    """``machine.WDT``: ``expired`` once two feeds were more than ``timeout_ms`` apart (the
    twin then resets the MCU); ``max_gap_ms`` the longest gap seen."""

    def __init__(self, world, timeout_ms):
        self.world = world
        self.timeout_ms = timeout_ms
        self.last = world.now
        self.max_gap_ms = 0.0
        self.expired = False

    def feed(self):
        gap = (self.world.now - self.last) * 1000
        self.max_gap_ms = max(self.max_gap_ms, gap)
        if gap > self.timeout_ms:
            self.expired = True
        self.last = self.world.now

    def check(self):
        """True if the watchdog fired by now (no feed for ``timeout_ms``)."""
        if (self.world.now - self.last) * 1000 > self.timeout_ms:
            self.expired = True
        return self.expired


class Pin:
    """``machine.Pin``'s ``value()``: read through ``read()``, written through ``write(v)``."""

    def __init__(self, read=None, write=None):
        self._read, self._write = read, write

    def value(self, v=None):
        if v is None:
            return self._read()
        self._write(v)
        return None


class Spi:
    """``machine.SPI`` (mode 0, ``hz``) plus its CS and IRQ pins (``cs``, ``irq``) on the
    world's gateware engine.  ``faults``: the world's active fault set, read per call."""

    def __init__(self, world, hz=10.5e6):
        self.world = world
        self.hz = hz
        self.cs = Pin(read=lambda: self._cs, write=self._set_cs)
        self.irq = Pin(read=self._irq)
        self._cs = 1
        self._byte = 0
        self.bytes = 0

    def _irq(self):
        self.world.catch_up()
        real = 1 if self.world.engine.irq() else 0
        for name, value in (("irq-stuck-high", 1), ("irq-stuck-low", 0)):
            if self.world.active(name):
                if value != real:
                    self.world.count_fault(name)     # the line lies this time
                return value
        return real

    def _set_cs(self, v):
        v = 1 if v else 0
        if v == self._cs:
            return
        self._cs = v
        if not v:
            self.world.catch_up()
            self._byte = 0
        self.world.engine.cs(v)

    def write_readinto(self, out, into):
        data = bytearray(out)
        if self.world.active("mosi-flip") and self._byte == 0 and data:
            data[0] ^= 0x01                      # the opcode's low bit
            self.world.count_fault("mosi-flip")
        got = self.world.engine.xfer(data)
        if self._byte == 0 and bytes(data[:2]) == _SOFT_RESET:
            self.world.soft_reset()              # the gateware's frame counter restarts
        if self.world.active("miso-flip") and len(got) > 40 and self._byte >= 2:
            got[40] ^= 0x10                      # one bit inside a packet read
            self.world.count_fault("miso-flip")
        self._byte += len(got)
        self.bytes += len(got)
        into[:len(got)] = got
        self.world.spend(8 * len(got) / self.hz)

    def write(self, out):
        self.write_readinto(out, bytearray(len(out)))

    def readinto(self, into, write=0):
        self.write_readinto(bytes((write,)) * len(into), into)


class I2c:
    """``machine.I2C`` to the world's sensor chip, each access costing its wire time; the
    chip does not answer while the ``sensor-silent`` fault is active."""

    def __init__(self, world):
        self.world = world

    def _chip(self):
        self.world.catch_up()
        self.world.spend(I2C_BITS / I2C_HZ)
        silent = self.world.active("sensor-silent")
        if silent:
            self.world.count_fault("sensor-silent")
        self.world.chip.answering = not silent
        return self.world.chip

    def writeto_mem(self, addr, reg, buf):
        self._chip().writeto_mem(addr, reg, buf)

    def readfrom_mem(self, addr, reg, n):
        return self._chip().readfrom_mem(addr, reg, n)

