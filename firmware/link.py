"""The MCU's SPI master of the FPGA link (``lodestar.contract.link``): status word, packets,
registers with read-back, the ID word, soft reset and flush; never raises, bounded in time.

    link = Link(machine.SPI(1, baudrate=10_500_000), Pin("A4", Pin.OUT, value=1),
                Pin("B0", Pin.IN), time, capacity=contract.FLIGHT_RECORD_CAPACITY)
    if link.wait_irq(250) and link.read_status() == OK:
        code, n = link.read_packet()          # the packet is link.packet(n) (a memoryview)

``spi``: an object with ``machine.SPI``'s ``write(buf)``, ``readinto(buf, write)`` and
``write_readinto(out, in)``; ``cs`` and ``irq``: objects with ``machine.Pin``'s ``value()``
(CS active low, driven here; ``irq`` high while a packet is being delivered); ``clock``: an
object with ``ticks_ms()``, ``ticks_diff(a, b)`` and ``sleep_ms(n)`` (MicroPython's ``time``
module; tests pass a simulated clock).  A bus call that raises ``OSError`` is a bus error.

Every result is a code of this module (:data:`OK` ... ), and every kind of error increments
its counter in :attr:`Link.counters` (an ``array('H')``, saturating, indexed in the order of
:data:`COUNTER_NAMES`).  The packet buffer holds ``capacity`` records;
a packet is trusted only after its header's magic, version and ``n_records`` (at most
``capacity``) pass and its CRC-32 matches; any other read leaves the stream possibly
mid-packet, so the link resynchronises: FLUSH (the gateware drops what is queued), then it
drains ``READ_STREAM`` while ``irq`` stays high (bounded by the longest packet and a time
limit), then a status read absorbs the underruns of the drain.  Buffers are allocated once
here; a frame allocates only a few small objects (views of the packet's variable-length parts,
the CRC-32 the port's ``binascii`` returns, compared byte by byte; 32-bit values are long ints
only above 2**30: a timestamp after 17.9 min of the gateware's clock), ``docs/mcu_board.md``.
Pure Python for CPython and MicroPython (docs/mcu_board.md).
"""

import struct
from array import array

try:
    from micropython import const
except ImportError:         # CPython
    def const(value):
        return value

from lodestar.contract import link as _link
from lodestar.contract.detection import FLIGHT_RECORD_CAPACITY, MAX_RECORD_CAPACITY
from lodestar.contract.integers import field_offsets
from lodestar.contract.packet import (
    CRC_BYTES,
    HEADER_BYTES,
    PACKET_MAGIC,
    PACKET_VERSION,
    crc32,
    packet_bytes,
)

# result codes
OK = 0
BUS_ERROR = 1            # the SPI or a pin raised OSError
STATUS_BAD = 2           # status reply failed its CRC-8 or its turnaround bytes
IRQ_TIMEOUT = 3          # no packet within the wait
HEADER_BAD = 4           # packet magic or version wrong: the stream is not at a packet start
LENGTH_BAD = 5           # n_records beyond the buffer or the contract
PACKET_CRC = 6           # CRC-32 of a packet of plausible length wrong
VERIFY_FAILED = 7        # a register read back another value than written
ID_BAD = 8               # no ID magic, or another link version
RESYNC_FAILED = 9        # irq still high after draining the longest packet
BAD_ARGUMENT = 10        # unknown register, value out of its field
CODE_NAMES = ("OK", "BUS_ERROR", "STATUS_BAD", "IRQ_TIMEOUT", "HEADER_BAD", "LENGTH_BAD",
              "PACKET_CRC", "VERIFY_FAILED", "ID_BAD", "RESYNC_FAILED", "BAD_ARGUMENT")

# counters (indices into Link.counters, in COUNTER_NAMES' order; const with private names:
# not kept in the module's globals on the MCU)
_C_BUS = const(0)                # bus errors
_C_STATUS_BAD = const(1)         # status replies rejected (CRC-8, turnaround)
_C_IRQ_TIMEOUT = const(2)        # waits for irq that timed out
_C_HEADER_BAD = const(3)         # packets with a wrong magic or version
_C_LENGTH_BAD = const(4)         # packets whose n_records exceeds the buffer or the contract
_C_PACKET_CRC = const(5)         # packets with a wrong CRC-32
_C_VERIFY = const(6)             # register read-backs that differed
_C_RESYNC = const(7)             # resynchronisations (flush + drain)
_C_RESYNC_FAILED = const(8)      # drains that did not see irq fall
_C_SLAVE_ERRORS = const(9)       # the slave's own ``errors`` count, accumulated
_C_UNDERRUNS = const(10)         # the slave's ``underruns`` (bytes read past the stream's end)
_C_FRAMES_SKIPPED = const(11)    # frames between two status reads beyond one (counter jumps)
_C_OVERFLOW = const(12)          # status reads with any overflow flag
_C_CLOCK_LOST = const(13)        # status reads with OVF_CLOCK_LOST
_C_PACKETS = const(14)           # packets read whole with a good CRC
_C_STATUS = const(15)            # status reads accepted
_C_RESTARTS = const(16)          # frame counter restarts the MCU did not command (no soft
                                 # reset, no OVF_CLOCK_LOST): the detector was reset behind
                                 # its back
COUNTER_NAMES = ("bus", "status_bad", "irq_timeout", "header_bad", "length_bad",
                 "packet_crc", "verify", "resync", "resync_failed", "slave_errors",
                 "underruns", "frames_skipped", "overflow", "clock_lost", "packets", "status",
                 "restarts")
N_COUNTERS = 17
_COUNTER_MAX = const(0xFFFF)

_REPLY = 1 + _link.TURNAROUND_BYTES            # MISO bytes before a read's reply
_STATUS_LEN = _REPLY + _link.STATUS_BYTES
_READ_LEN = _link.READ_REG_BYTES
_ID_LEN = _link.ID_FIRST_REPLY + _link.ID_BYTES


def _specs(fields, names):
    """Fields ``names`` of a field table (``contract.field_offsets``), each as one small
    int: its bit offset from the MSB << 8 | its bits."""
    table = field_offsets(fields)
    out = []
    for name in names:
        for field, at, bits in table:
            if field == name:
                out.append(at << 8 | bits)
    return out


_SPECS = array("l", _specs(_link.HEADER_FIELDS, ("magic", "version", "frame_counter",
                                                 "timestamp", "height", "flags", "n_records")) +
               _specs(_link.STATUS_FIELDS, ("frame_counter", "errors", "underruns", "overflow",
                                            "busy", "trained", "eye_width")))
"""The header's and the status word's fields the master reads (:func:`_specs`), indexed by
the ``_H_*`` and ``_S_*`` constants: one array, where a dict of tuples per table kept 600
bytes of heap on the MCU and a global per field 16 more each."""
_H_MAGIC = const(0)
_H_VERSION = const(1)
_H_COUNTER = const(2)
_H_TIMESTAMP = const(3)
_H_HEIGHT = const(4)
_H_FLAGS = const(5)
_H_RECORDS = const(6)
_S_COUNTER = const(7)
_S_ERRORS = const(8)
_S_UNDERRUNS = const(9)
_S_OVERFLOW = const(10)
_S_BUSY = const(11)
_S_TRAINED = const(12)
_S_EYE_WIDTH = const(13)


def _field(data, base, k):
    """Unsigned field ``_SPECS[k]`` of the big-endian bytes at ``base``."""
    spec = _SPECS[k]
    at = spec >> 8
    bits = spec & 0xFF
    first = base + at // 8
    last = base + (at + bits - 1) // 8
    value = 0
    for i in range(first, last + 1):
        value = (value << 8) | data[i]
    if not (at | bits) & 7:
        return value                     # byte aligned: no shift or mask (no long ints)
    return (value >> (7 - (at + bits - 1) % 8)) & ((1 << bits) - 1)


DRAIN_CHUNK = 32
"""Bytes per ``READ_STREAM`` while draining (``irq`` checked between chunks)."""
DRAIN_MS = 50
"""Longest drain (ms); the longest packet takes 12 ms at 10.5 MHz."""


class Link(object):
    """The master on one SPI bus (module docstring).  ``capacity``: records the packet
    buffer holds (the gateware's ``record_capacity`` must not exceed it, or every full frame
    is refused as ``LENGTH_BAD``); ``retries``: extra attempts of a register write whose
    read-back differs."""

    def __init__(self, spi, cs, irq, clock, capacity=FLIGHT_RECORD_CAPACITY, retries=2):
        self.spi = spi
        self.cs = cs
        self.irq = irq
        self.clock = clock
        self.capacity = max(0, min(int(capacity), MAX_RECORD_CAPACITY))
        self.retries = retries
        self.counters = array("H", [0] * N_COUNTERS)
        self.buf = bytearray(packet_bytes(self.capacity))
        self._mv = memoryview(self.buf)
        self._head = self._mv[:HEADER_BYTES]
        self._tx = bytearray(max(_STATUS_LEN, _READ_LEN, _ID_LEN, _link.WRITE_REG_BYTES))
        self._rx = bytearray(len(self._tx))
        self._txv = memoryview(self._tx)
        self._rxv = memoryview(self._rx)
        # the (tx, rx) views of each fixed-length transaction, made once (a slice is a heap
        # object)
        self._v_status = self._views(_STATUS_LEN)
        self._v_read = self._views(_READ_LEN)
        self._v_id = self._views(_ID_LEN)
        self._v_write = self._views(_link.WRITE_REG_BYTES)
        self._status_data = self._rxv[_REPLY:_STATUS_LEN]
        self._stream_op = bytearray((_link.OP_READ_STREAM,) + (0,) * _link.TURNAROUND_BYTES)
        self._crc = bytearray(CRC_BYTES)   # the CRC-32 computed, big endian (compared
                                             # byte by byte: no long ints built)
        # the last status word read (valid after read_status() == OK)
        self.frame_counter = None
        self.errors = 0
        self.underruns = 0
        self.overflow = 0
        self.busy = 0
        self.trained = 0                 # the LVDS receiver's phase training (DE2-115; 0 on
        self.eye_width = 0               # the MT9P031 boards): its error-free phase steps
        self.last_frame_counter = None   # the frame counter of the last good packet
        self.last_stamp = None           # its timestamp's low 30 bits (the gateware's us
                                         # counter: a small int on the MCU, _read_stamp)
        self.last_stamp_top = 0          # and its top 2 bits
        self.n_records = 0
        self.last_height = 0             # the rows of the last good packet's frame
        self.last_flags = 0              # its frame flags (contract FRAME_*)
        self.ident = None                # (link_version, build) after read_id() == OK
        self.irq_edge = False            # the last wait_irq() saw irq rise (not high at once)
        self.restarted = False           # an uncommanded restart seen; the caller clears it
        self._drain_underruns = False
        self._reset_sent = False         # a soft reset since the last status read

    # ---- counters ----------------------------------------------------------------------

    def count(self, index, n=1):
        value = self.counters[index] + n
        self.counters[index] = value if value < _COUNTER_MAX else _COUNTER_MAX

    def counter(self, name):
        """A counter by its name in :data:`COUNTER_NAMES` (0 for an unknown name)."""
        for i in range(N_COUNTERS):
            if COUNTER_NAMES[i] == name:
                return self.counters[i]
        return 0

    # ---- transactions ------------------------------------------------------------------

    def _select(self, on):
        self.cs.value(0 if on else 1)

    def _views(self, n):
        return self._txv[:n], self._rxv[:n]

    def _exchange(self, views):
        """One transaction of ``views`` = (the first bytes of ``_tx``, as many of ``_rx``)
        for the reply: True if the bus did not fail."""
        try:
            self._select(True)
            try:
                self.spi.write_readinto(views[0], views[1])
            finally:
                self._select(False)
        except OSError:
            self.count(_C_BUS)
            return False
        return True

    def _clear(self, n):
        tx = self._tx
        for i in range(n):
            tx[i] = 0

    def wait_irq(self, timeout_ms, tick=None):
        """Wait until ``irq`` is high, at most ``timeout_ms``: True if it is.  ``irq_edge``
        says whether it rose during the wait (its ticks are then the frame's arrival) rather
        than being high at once; ``tick()``, if given, is called after every 1 ms poll."""
        clock = self.clock
        self.irq_edge = False
        try:
            if self.irq.value():
                return True
            start = clock.ticks_ms()
            while clock.ticks_diff(clock.ticks_ms(), start) < timeout_ms:
                clock.sleep_ms(1)
                if self.irq.value():
                    self.irq_edge = True
                    return True
                if tick is not None:
                    tick()
        except OSError:
            self.count(_C_BUS)
            return False
        self.count(_C_IRQ_TIMEOUT)
        return False

    def read_status(self):
        """Read and check the status word; its fields land in ``frame_counter``, ``errors``,
        ``underruns``, ``overflow``, ``busy``, ``trained``, ``eye_width`` (the LVDS
        receiver's eye, ``lodestar.contract.link.STATUS_FIELDS``), and the counters add
        them up.  Returns a code (``STATUS_BAD``: CRC-8 or turnaround wrong; the fields
        keep their old values)."""
        self._clear(_STATUS_LEN)
        self._tx[0] = _link.OP_READ_STATUS
        if not self._exchange(self._v_status):
            return BUS_ERROR
        rx = self._rx
        for i in range(_REPLY):
            if rx[i] != _link.FILLER:
                self.count(_C_STATUS_BAD)
                return STATUS_BAD
        if _link.crc8(self._status_data, _link.STATUS_DATA_BYTES) != rx[_STATUS_LEN - 1]:
            self.count(_C_STATUS_BAD)
            return STATUS_BAD
        previous = self.frame_counter
        self.frame_counter = _field(rx, _REPLY, _S_COUNTER)
        self.errors = _field(rx, _REPLY, _S_ERRORS)
        self.underruns = _field(rx, _REPLY, _S_UNDERRUNS)
        self.overflow = _field(rx, _REPLY, _S_OVERFLOW)
        self.busy = _field(rx, _REPLY, _S_BUSY)
        self.trained = _field(rx, _REPLY, _S_TRAINED)
        self.eye_width = _field(rx, _REPLY, _S_EYE_WIDTH)
        self.count(_C_STATUS)
        self.count(_C_SLAVE_ERRORS, self.errors)
        if self._drain_underruns:
            self._drain_underruns = False        # the drain's own reads past the end
        else:
            self.count(_C_UNDERRUNS, self.underruns)
        if self.overflow:
            self.count(_C_OVERFLOW)
        if self.overflow & (1 << _link.OVF_CLOCK_LOST):
            self.count(_C_CLOCK_LOST)
        commanded = self._reset_sent
        self._reset_sent = False
        if previous is not None:
            step = self.frame_counter - previous
            if step < 0:                         # modulo 2**32 (a long int only here)
                step += 0x100000000
            if 1 < step < 0x80000000:
                self.count(_C_FRAMES_SKIPPED, min(step - 1, _COUNTER_MAX))
            elif step >= 0x80000000 and not commanded and not self.clock_lost():
                self.count(_C_RESTARTS)
                self.restarted = True
        return OK

    def clock_lost(self):
        """The last status word's ``OVF_CLOCK_LOST`` flag."""
        return bool(self.overflow & (1 << _link.OVF_CLOCK_LOST))

    def _stream(self, view):
        """One ``READ_STREAM`` transaction that fills ``view``: True if the bus did not
        fail."""
        try:
            self._select(True)
            try:
                self.spi.write(self._stream_op)
                self.spi.readinto(view, 0)
            finally:
                self._select(False)
        except OSError:
            self.count(_C_BUS)
            return False
        return True

    def read_packet(self):
        """Read one packet into :attr:`buf`: ``(code, n_records)``; on ``OK`` the packet is
        ``packet(n_records)``.  The header is read first and its magic, version and
        ``n_records`` checked before the rest is read; a refused or corrupt packet
        resynchronises the stream (:meth:`resync`) before returning its code."""
        self.n_records = 0
        head = self._head
        if not self._stream(head):
            self.resync()
            return BUS_ERROR, 0
        if _field(head, 0, _H_MAGIC) != PACKET_MAGIC or \
                _field(head, 0, _H_VERSION) != PACKET_VERSION:
            self.count(_C_HEADER_BAD)
            self.resync()
            return HEADER_BAD, 0
        n = _field(head, 0, _H_RECORDS)
        if n > self.capacity:
            self.count(_C_LENGTH_BAD)
            self.resync()
            return LENGTH_BAD, 0
        total = packet_bytes(n)
        if not self._stream(self._mv[HEADER_BYTES:total]):
            self.resync()
            return BUS_ERROR, 0
        body = total - CRC_BYTES
        buf = self.buf
        crc = self._crc
        struct.pack_into(">I", crc, 0, crc32(self._mv[:body]))
        if crc[0] != buf[body] or crc[1] != buf[body + 1] or crc[2] != buf[body + 2] or \
                crc[3] != buf[body + 3]:
            self.count(_C_PACKET_CRC)
            self.resync()
            return PACKET_CRC, 0
        self.count(_C_PACKETS)
        self.n_records = n
        self.last_frame_counter = _field(head, 0, _H_COUNTER)
        self._read_stamp(head)
        self.last_height = _field(head, 0, _H_HEIGHT)
        self.last_flags = _field(head, 0, _H_FLAGS)
        return OK, n

    def _read_stamp(self, head):
        """The header's 32-bit ``timestamp`` as its low 30 bits (``last_stamp``) and its top 2
        (``last_stamp_top``): MicroPython's small ints hold 30 bits and a sign on this port,
        so a whole stamp above 2**30 (after 17.9 min of the gateware's clock) would be a long
        int, made on the heap in every frame.  The field is 32 bits on a byte boundary
        (``contract.HEADER_FIELDS``, checked by the tests)."""
        at = _SPECS[_H_TIMESTAMP] >> 11
        top = head[at]
        self.last_stamp = ((top & 0x3F) << 24) | (head[at + 1] << 16) | \
            (head[at + 2] << 8) | head[at + 3]
        self.last_stamp_top = top >> 6

    def timestamp(self):
        """The last good packet's whole 32-bit ``timestamp`` (None before one; a long int
        above 2**30 on the MCU: for the ground and tests, the loop uses ``last_stamp``)."""
        if self.last_stamp is None:
            return None
        return (self.last_stamp_top << 30) | self.last_stamp

    def packet(self, n_records):
        """The packet of ``n_records`` records in the buffer, as a memoryview."""
        return self._mv[:packet_bytes(n_records)]

    def resync(self):
        """Put the stream back at a packet start: FLUSH, then drain ``READ_STREAM`` while
        ``irq`` is high (at most the longest packet and :data:`DRAIN_MS`), then read the
        status (its underruns are the drain's).  Returns ``OK`` or ``RESYNC_FAILED``."""
        self.count(_C_RESYNC)
        self.command(_link.OP_FLUSH)
        limit = packet_bytes(MAX_RECORD_CAPACITY)
        drained = 0
        clock = self.clock
        scratch = self._mv[:min(DRAIN_CHUNK, len(self.buf))]
        try:
            start = clock.ticks_ms()
            while self.irq.value():
                if drained >= limit or clock.ticks_diff(clock.ticks_ms(), start) > DRAIN_MS:
                    self.count(_C_RESYNC_FAILED)
                    return RESYNC_FAILED
                if not self._stream(scratch):
                    return RESYNC_FAILED
                drained += len(scratch)
        except OSError:
            self.count(_C_BUS)
            return RESYNC_FAILED
        self._drain_underruns = True
        self.read_status()
        return OK

    def command(self, opcode):
        """Send a keyed command (``OP_SOFT_RESET``, ``OP_FLUSH``): a code.  Its two bytes
        are made per command (rare: a resynchronisation or a reset), not kept."""
        if opcode not in _link.KEYED_OPCODES:
            return BAD_ARGUMENT
        data = _link.keyed_command(opcode)
        try:
            self._select(True)
            try:
                self.spi.write(data)
            finally:
                self._select(False)
        except OSError:
            self.count(_C_BUS)
            return BUS_ERROR
        return OK

    def soft_reset(self):
        """Reset the detector datapath (registers kept), then resynchronise: a code."""
        self._reset_sent = True
        code = self.command(_link.OP_SOFT_RESET)
        if code != OK:
            return code
        return self.resync()

    def read_reg(self, address):
        """``(code, value)`` of the register at word ``address``."""
        self._clear(_READ_LEN)
        self._tx[0] = _link.OP_READ_REG
        self._tx[1] = address & 0xFF
        if not self._exchange(self._v_read):
            return BUS_ERROR, 0
        rx = self._rx
        at = _link.READ_REG_FIRST_REPLY
        value = 0
        for i in range(_link.VALUE_BYTES):
            value = (value << 8) | rx[at + i]
        return OK, value

    def write_reg(self, name, value):
        """Write register ``name`` (``contract.REGISTERS``) and read it back, retrying
        ``retries`` times: a code (``VERIFY_FAILED`` if it never reads back ``value``;
        the gateware refuses values outside a register's limits, so those fail too)."""
        reg = _link.REGISTER_BY_NAME.get(name)
        if reg is None or not isinstance(value, int) or value < 0 or value >> reg.bits:
            return BAD_ARGUMENT
        code = VERIFY_FAILED
        for _attempt in range(1 + self.retries):
            tx = self._tx
            tx[0] = _link.OP_WRITE_REG
            tx[1] = reg.address
            for i in range(_link.VALUE_BYTES):
                tx[2 + i] = (value >> (8 * (_link.VALUE_BYTES - 1 - i))) & 0xFF
            if not self._exchange(self._v_write):
                code = BUS_ERROR
                continue
            code, back = self.read_reg(reg.address)
            if code == OK and back == value:
                return OK
            if code == OK:
                self.count(_C_VERIFY)
                code = VERIFY_FAILED
        return code

    def read_id(self):
        """Read the gateware ID word: a code (``ID_BAD`` without the magic or with another
        link version); ``ident`` = ``(link_version, build)``."""
        self._clear(_ID_LEN)
        self._tx[0] = _link.OP_READ_ID
        if not self._exchange(self._v_id):
            return BUS_ERROR
        rx = self._rx
        at = _link.ID_FIRST_REPLY
        if ((rx[at] << 8) | rx[at + 1]) != _link.ID_MAGIC or rx[at + 2] != _link.LINK_VERSION:
            self.ident = None
            return ID_BAD
        self.ident = (rx[at + 2], rx[at + 3])
        return OK
