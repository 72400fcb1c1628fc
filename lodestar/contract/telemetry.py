"""The flight executive's telemetry record, MCU -> ground: one fixed-size record per step,
written by ``lodestar.firmware.executive`` and read on the ground by :func:`decode`.  Its
layout is here, once; the executive's states, health counters and time tags are described
in ``docs/mcu_board.md`` (Telemetry).  MicroPython-safe (the MCU imports it; not part of
``from lodestar import contract as C``, so the MCU's contract namespace does not carry it).
"""

import struct

from lodestar.contract.packet import crc32

MAGIC = 0x4C54        # "LT"
VERSION = 3
"""3: the attitude's time tag is its result's ``t_epoch_s`` on the header ``timestamp``'s
clock, ``epoch_us`` added, health counters ``time_mismatch`` and ``missed``; 2: the header
timestamp and ``uncommanded_reset``."""

FIELDS = ("magic", "version", "state", "sequence", "time_ms", "frame_counter",
          "frame_timestamp", "epoch_us", "status", "link_code", "matches", "level",
          "n_records", "min_sum", "qx", "qy", "qz", "qw", "sigma_cross", "sigma_roll",
          "frames", "ok", "bad", "irq_timeout", "link_fault", "coasted", "lost", "resync",
          "detector_reset", "sensor_init", "safe", "clock_lost", "sensor_fault", "reg_fault",
          "commands", "internal", "uncommanded_reset", "rate_contradicted", "time_mismatch",
          "missed", "heap_free", "crc")
"""The record's values in order (one literal: a constant tuple in the MCU's flash): magic,
version, state, sequence, the attitude's time tag (ms of spacecraft time, the instant its
result's ``t_epoch_s`` names), FPGA frame counter and FPGA timestamp of its frame (us, the
packet header's: the frame's first pixel on the gateware's clock), ``epoch_us`` (the
attitude's instant on that clock, modulo 2**32), result status, link code, matches, recovery
level, records, min_sum, q (x, y, z, w; NaN without an attitude), sigma cross and roll
(arcsec; NaN), the health counters ``frames`` .. ``missed`` (:data:`HEALTH_NAMES`), heap free
(bytes; 0 unknown), CRC-32 (``contract.crc32``) of everything before it."""
HEALTH_AT = FIELDS.index("frames")
"""Index of the first health counter among the packed values."""
N_HEALTH = FIELDS.index("heap_free") - HEALTH_AT
HEALTH_NAMES = FIELDS[HEALTH_AT:HEALTH_AT + N_HEALTH]
"""The executive's health counters, in record order (its ``_H_*`` constants index them):
each a saturating 16-bit count since boot."""

FORMAT = ">HBBIQIIIBBBBHI4f2f" + str(N_HEALTH) + "HII"
"""Big endian, :data:`FIELDS` in order: 16-bit counters, float32 q and sigmas."""
BYTES = struct.calcsize(FORMAT)
PACK_FORMAT = FORMAT.replace("QIII", "QIHHHH", 1)
"""The same bytes as the MCU packs them: ``frame_timestamp`` and ``epoch_us`` each as two
16-bit halves (high, low), since the executive keeps 32-bit timestamps as small ints of 30
bits and 2 (a whole one above 2**30 would be a long int on the heap in every record)."""


def decode(data):
    """The record as a dict of :data:`FIELDS` (ground side), or None when its length,
    magic, version or CRC-32 is wrong."""
    if len(data) != BYTES:
        return None
    data = bytes(data)
    values = struct.unpack(FORMAT, data)
    if crc32(data[:BYTES - 4]) != values[-1] or values[0] != MAGIC or values[1] != VERSION:
        return None
    out = {}
    for i in range(len(FIELDS)):
        out[FIELDS[i]] = values[i]
    return out
