"""The twin's golden gateware engine: the board top level modelled in Python with the same
interface as :class:`lodestar.fly.verilated.VerilatedTop`.  The golden detector
(:class:`lodestar.golden.Detector`, bit-exact with the gateware) detects each frame with the
register bank's values, the ground codec makes its packet, and a byte-level model of the
contract's SPI slave (``lodestar.contract.link``) serves the MCU: opcode, turnaround,
replies, ``FILLER`` elsewhere, the status word with its CRC-8, keyed FLUSH and SOFT_RESET,
register writes refused outside ``contract.register_range``, ``errors`` and ``underruns``.

What is a model here (the Verilated engine has the real thing): the packet queue holds the
packet being delivered and one more (a frame that finds both waiting is lost and raises
``OVF_TRAILER_LOST``); a frame that ends early (``rows`` short) is completed with dark pixels
and flagged ``FRAME_TIMEOUT``, as the frame watchdog does; a soft reset or flush empties the
queue; ``busy`` reads 0.
"""

import numpy as np

from lodestar import contract as C
from lodestar.golden import Detector, DetectorConfig
from lodestar.ground import codec

QUEUE = 2
"""Packets the model holds for the MCU (the one being delivered and the held trailer's)."""


def config_of(bank, width, height, pixel_bits, record_capacity, label_capacity):
    """The ``DetectorConfig`` of register bank ``bank`` (``{address: value}``)."""
    v = {r.name: bank[r.address] for r in C.REGISTERS}
    return DetectorConfig(
        width=width, height=height, pixel_bits=pixel_bits,
        threshold_mode=C.MODE_NAMES[v["mode"]], threshold=v["threshold"],
        background=v["background"], ksigma=v["ksigma"] / (1 << C.KSIGMA_FRAC_BITS),
        local_log2_window=v["local_log2_window"], local_offset=v["local_offset"],
        min_pixels=v["min_pixels"], min_sum=v["min_sum"],
        max_pixels=None if v["max_pixels"] == C.MAX_PIXELS_UNLIMITED else v["max_pixels"],
        label_capacity=label_capacity, record_capacity=record_capacity)


class GoldenTop:
    """The model (module docstring) of a top with this geometry and capacities."""

    def __init__(self, width, height, pixel_bits, record_capacity, label_capacity=None,
                 build_id=0):
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.record_capacity, self.label_capacity = record_capacity, label_capacity
        self.build_id = build_id
        self.bank = {r.address: r.reset for r in C.REGISTERS}
        self.detector = Detector(self._config())
        self.queue = []
        self.delivering = bytearray()
        self.errors = self.underruns = 0
        self.sticky = 0
        self.losses = self.losses_seen = 0
        self._selected = False
        self._rx = bytearray()
        self._status_bytes = b""       # the status word captured at a READ_STATUS opcode

    def _config(self):
        return config_of(self.bank, self.width, self.height, self.pixel_bits,
                         self.record_capacity, self.label_capacity)

    # ---- pixels ------------------------------------------------------------------------

    def irq(self):
        return bool(self.delivering or self.queue)

    def frame(self, pixels, rows=None, start_us=0):
        """Detect ``pixels`` (its first ``rows`` rows, the rest dark and flagged) and queue
        its packet, stamped ``start_us`` (its first pixel on the gateware's microsecond
        counter)."""
        frame = np.asarray(pixels, dtype=np.uint16)
        flags = 0
        if frame.shape != (self.height, self.width):      # another window: a line error
            fixed = np.zeros((self.height, self.width), dtype=np.uint16)
            h, w = min(self.height, frame.shape[0]), min(self.width, frame.shape[1])
            fixed[:h, :w] = frame[:h, :w]
            frame, flags = fixed, C.FRAME_LINE_ERROR
        if rows is not None and rows < self.height:
            frame = frame.copy()
            frame[max(rows, 0):] = 0
            flags |= C.FRAME_TIMEOUT
        self.detector.configure(self._config())
        result = self.detector.process(frame)
        result.flags |= flags
        result.timestamp = int(start_us) & ((1 << C.TIMESTAMP_BITS) - 1)
        if len(self.queue) + bool(self.delivering) >= QUEUE:
            self.sticky |= 1 << C.OVF_TRAILER_LOST
            return
        self.queue.append(codec.encode(result))

    def pll_loss(self):
        self.losses += 1

    def accepts(self):
        """False when a frame ending now would find the queue full (its packet lost)."""
        return len(self.queue) + bool(self.delivering) < QUEUE

    def skip(self):
        """A frame whose packet is lost: counted, not detected (``OVF_TRAILER_LOST``)."""
        self.detector.frame_counter = (self.detector.frame_counter + 1) & 0xFFFFFFFF
        self.sticky |= 1 << C.OVF_TRAILER_LOST

    # ---- the SPI slave ---------------------------------------------------------------------

    def cs(self, level):
        if not level:
            self._selected = True
            self._rx = bytearray()
            return
        if self._selected and len(self._rx) and self._rx[0] == C.OP_WRITE_REG and \
                len(self._rx) < C.WRITE_REG_BYTES:
            self.errors += 1                     # aborted write
        self._selected = False

    def xfer(self, mosi):
        out = bytearray(len(mosi))
        for i, byte in enumerate(mosi):
            out[i] = self._reply(len(self._rx))
            self._rx.append(byte)
            self._received(len(self._rx) - 1, byte)
        return out

    def _status(self):
        overflow = self.sticky
        if self.losses != self.losses_seen:
            overflow |= 1 << C.OVF_CLOCK_LOST
        return C.encode_status({"frame_counter": self.detector.frame_counter & 0xFFFFFFFF,
                                "errors": min(self.errors, 255),
                                "underruns": min(self.underruns, 255),
                                "overflow": overflow, "busy": 0})

    def _reply(self, i):
        """The MISO byte of byte ``i`` of the transaction (known from the bytes before)."""
        rx = self._rx
        if i == 0:
            return C.FILLER
        op = rx[0]
        reply = i - 1 - C.TURNAROUND_BYTES
        if op == C.OP_READ_STATUS and 0 <= reply < C.STATUS_BYTES:
            return self._status_bytes[reply]
        if op == C.OP_READ_ID and 0 <= reply < C.ID_BYTES:
            return C.gateware_id(self.build_id).to_bytes(C.ID_BYTES, "big")[reply]
        if op == C.OP_READ_REG and i >= C.READ_REG_FIRST_REPLY:
            k = i - C.READ_REG_FIRST_REPLY
            if k < C.VALUE_BYTES:
                return self.bank.get(rx[1], 0).to_bytes(C.VALUE_BYTES, "big")[k]
            return C.FILLER
        if op == C.OP_READ_STREAM and reply >= 0:
            if not self.delivering and self.queue:
                self.delivering = bytearray(self.queue.pop(0))
            if self.delivering:
                return self.delivering.pop(0)
            self.underruns += 1
        return C.FILLER

    def _received(self, i, byte):
        """Act on MOSI byte ``i`` of the transaction."""
        op = self._rx[0]
        if i == 0:
            if op not in C.OPCODES:
                self.errors += 1
            if op == C.OP_READ_STATUS:
                self._status_bytes = self._status()
                self.errors = self.underruns = 0
                self.sticky = 0
                self.losses_seen = self.losses
            return
        if op in C.KEYED_OPCODES and i == 1:
            if byte != C.command_key(op):
                self.errors += 1
            elif op == C.OP_FLUSH:
                self.queue, self.delivering = [], bytearray()
            else:
                self.queue, self.delivering = [], bytearray()
                self.detector.reset()
        if op == C.OP_WRITE_REG and i == C.WRITE_REG_BYTES - 1:
            self._write(self._rx[1], int.from_bytes(bytes(self._rx[2:]), "big"))

    def _write(self, address, value):
        reg = next((r for r in C.REGISTERS if r.address == address), None)
        if reg is None:
            self.errors += 1
            return
        low, high = C.register_range(reg.name, self.pixel_bits)
        if not low <= value <= high:
            self.sticky |= 1 << C.OVF_REG_REFUSED
            return
        self.bank[address] = value
