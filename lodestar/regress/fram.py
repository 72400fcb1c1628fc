"""A model of the star database's SPI F-RAM as the MCU's bus sees it: the ``machine.SPI``
and chip-select ``Pin`` that :meth:`lodestar.firmware.database.Database.fram` reads through,
over a backing store instead of the chip.  Pure Python for CPython (the tests: the store is
an ``io.BytesIO`` of the image) and MicroPython (the Cortex-M4F build under QEMU: a host file
read by semihosting, :mod:`lodestar.regress.semihost`).

The chip is a 4-Mbit (512 KiB) serial F-RAM of the Cypress/Infineon FM25V-/CY15B104Q-class:
SPI mode 0, ``READ`` = opcode ``0x03`` then a 24-bit big-endian address, then data for as
long as CS stays low (the address increments and wraps at the end of the array); there is no
busy time, so a read's time is its wire time.  Anything but ``READ`` (the model serves no
writes) and a read without its address are counted in :attr:`Fram.errors` and read as
``0xFF`` (a floating MISO).  :attr:`Fram.reads` and :attr:`Fram.read_bytes` count the
transactions and data bytes that a frame's wire time is computed from
(:func:`wire_us`)."""

READ = 0x03
"""The F-RAM's read opcode (the firmware's copy: ``lodestar.firmware.database.FRAM_READ``)."""
ADDRESS_BYTES = 3
CAPACITY = 512 * 1024
"""Bytes of the 4-Mbit chip."""


def wire_us(reads, data_bytes, sck_hz):
    """Microseconds on the wire of ``reads`` ``READ`` transactions carrying ``data_bytes``
    in all, at an SPI clock of ``sck_hz``: each sends the opcode and the address (4 bytes)
    before its data; the bus's own set-up between transactions is not counted."""
    return (reads * (1 + ADDRESS_BYTES) + data_bytes) * 8 * 1e6 / sck_hz


class Fram(object):
    """The SPI side of the chip over ``store`` (an object with ``seek(pos)`` and
    ``readinto(buf)``, the image at address 0): ``write(buf)`` and ``readinto(buf,
    write=0)`` as ``machine.SPI``'s, one transaction between a CS fall and rise (:attr:`cs`,
    a ``Pin``-like object)."""

    def __init__(self, store, capacity=CAPACITY):
        self.store = store
        self.capacity = capacity
        self.cs = _ChipSelect(self)
        self.reads = 0
        self.read_bytes = 0
        self.errors = 0
        self._command = bytearray(1 + ADDRESS_BYTES)
        self._got = 0            # command bytes received in this transaction
        self._address = -1       # the read address once the command is whole

    def _begin(self):
        self._got = 0
        self._address = -1

    def write(self, buf):
        """Command bytes of the current transaction (the opcode, then the address)."""
        command = self._command
        for b in buf:
            if self._got < len(command):
                command[self._got] = b
                self._got += 1
                if self._got == len(command):
                    self._start()
        return None

    def _start(self):
        command = self._command
        if command[0] != READ:
            self.errors += 1
            return
        self._address = ((command[1] << 16) | (command[2] << 8) | command[3]) % self.capacity
        self.reads += 1

    def readinto(self, buf, write=0):
        """Data of the current read into ``buf`` (``0xFF`` without a ``READ``)."""
        n = len(buf)
        if self._address < 0:
            self.errors += 1
            for i in range(n):
                buf[i] = 0xFF
            return None
        end = self._address + n
        if end > self.capacity:                  # the array wraps: two reads of the store
            first = self.capacity - self._address
            self._read(buf, 0, self._address, first)
            self._read(buf, first, 0, n - first)
        else:
            self._read(buf, 0, self._address, n)
        self._address = end % self.capacity
        self.read_bytes += n
        return None

    def _read(self, buf, at, address, n):
        view = memoryview(buf)[at:at + n]
        self.store.seek(address)
        got = self.store.readinto(view)
        for i in range(got or 0, n):           # past the image: erased F-RAM reads 0xFF
            view[i] = 0xFF


class _ChipSelect(object):
    """The chip's CS pin: ``value(0)`` starts a transaction, ``value(1)`` ends it."""

    def __init__(self, chip):
        self.chip = chip
        self.level = 1

    def value(self, level=None):
        if level is None:
            return self.level
        if level == 0 and self.level == 1:
            self.chip._begin()
        self.level = 1 if level else 0
        return None

    def __call__(self, level=None):
        return self.value(level)
