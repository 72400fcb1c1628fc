"""The gateware's side of the SPI link (``lodestar.contract.link``) at the transaction level,
serving recorded packets to the firmware's :class:`lodestar.firmware.link.Link`: a
``machine.SPI``-like bus and the ``cs`` and ``irq`` pins.  It lets the flight executive run
on the Cortex-M4F build with its own link, buffers and telemetry
(:mod:`lodestar.regress.qemuloop`) where no FPGA is attached.  Pure Python for CPython and
MicroPython; a bus call allocates nothing but the status word's few bytes.

Served: ``READ_STATUS`` (the frame counter, no errors, its CRC-8), ``READ_ID`` (the
contract's magic and link version), ``WRITE_REG``/``READ_REG`` (a register file),
``READ_STREAM`` (the loaded packet, then filler bytes counted as underruns), the keyed
``FLUSH`` and ``SOFT_RESET`` (the queued packet dropped).  ``irq`` is high while a loaded
packet has bytes left, as the gateware's."""

from lodestar.contract import link

_REPLY = 1 + link.TURNAROUND_BYTES


class LinkModel(object):
    """The bus (``write``, ``readinto``, ``write_readinto``), :attr:`cs` and :attr:`irq`."""

    def __init__(self, build=0):
        self.ident = link.gateware_id(build)
        self.registers = {}
        self.packet = b""
        self.pos = 0
        self.frame_counter = 0
        self.underruns = 0
        self.streaming = False
        self.cs = _Pin(1)
        self.irq = _Irq(self)

    def load(self, packet):
        """Queue ``packet`` (bytes-like) as the next frame's."""
        self.packet = packet
        self.pos = 0
        self.frame_counter = (self.frame_counter + 1) & ((1 << link.FRAME_COUNTER_BITS) - 1)

    def pending(self):
        """Bytes of the loaded packet not read yet."""
        return len(self.packet) - self.pos

    def write(self, buf):
        op = buf[0]
        self.streaming = op == link.OP_READ_STREAM
        if len(buf) >= link.KEYED_BYTES and op in link.KEYED_OPCODES:
            self.pos = len(self.packet)              # FLUSH and SOFT_RESET drop the queue

    def readinto(self, buf, write=0):
        n = len(buf)
        if not self.streaming:
            for i in range(n):
                buf[i] = link.FILLER
            return
        left = len(self.packet) - self.pos
        take = n if n < left else left
        if take > 0:
            buf[:take] = self.packet[self.pos:self.pos + take]
            self.pos += take
        for i in range(take, n):
            buf[i] = link.FILLER
        self.underruns += n - take

    def write_readinto(self, out, into):
        op = out[0]
        self.streaming = False
        for i in range(len(into)):
            into[i] = link.FILLER
        if op == link.OP_READ_STATUS:
            underruns = self.underruns if self.underruns < 255 else 255
            self.underruns = 0
            word = link.encode_status({"frame_counter": self.frame_counter, "errors": 0,
                                       "underruns": underruns, "overflow": 0,
                                       "busy": 1 if self.pending() else 0})
            into[_REPLY:_REPLY + len(word)] = word
        elif op == link.OP_READ_ID:
            for i in range(link.ID_BYTES):
                into[link.ID_FIRST_REPLY + i] = (self.ident >> (8 * (link.ID_BYTES - 1 - i))) & 0xFF
        elif op == link.OP_WRITE_REG:
            value = 0
            for i in range(link.VALUE_BYTES):
                value = (value << 8) | out[2 + i]
            self.registers[out[1]] = value
        elif op == link.OP_READ_REG:
            value = self.registers.get(out[1], 0)
            for i in range(link.VALUE_BYTES):
                shift = 8 * (link.VALUE_BYTES - 1 - i)
                into[link.READ_REG_FIRST_REPLY + i] = (value >> shift) & 0xFF


class _Pin(object):
    def __init__(self, level):
        self.level = level

    def value(self, level=None):
        if level is None:
            return self.level
        self.level = level
        return None


class _Irq(object):
    def __init__(self, model):
        self.model = model

    def value(self):
        return 1 if self.model.pending() > 0 else 0
