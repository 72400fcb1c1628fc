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

HEALTH_NAMES = ("frames", "ok", "bad", "irq_timeout", "link_fault", "coasted", "lost",
                "resync", "detector_reset", "sensor_init", "safe", "clock_lost",
                "sensor_fault", "reg_fault", "commands", "internal", "uncommanded_reset",
                "rate_contradicted", "time_mismatch", "missed")
"""The executive's health counters, in record order (``executive.H_*`` index them): each a
saturating 16-bit count since boot."""
N_HEALTH = len(HEALTH_NAMES)

FORMAT = ">HBBIQIIIBBBBHI4f2f" + str(N_HEALTH) + "HII"
"""Big endian: magic, version, state, sequence, the attitude's time tag (ms of spacecraft
time, the instant its result's ``t_epoch_s`` names), FPGA frame counter and FPGA timestamp
of its frame (us, the packet header's: the frame's first pixel on the gateware's clock),
``epoch_us`` (the attitude's instant on that clock, modulo 2**32), result status, link
code, matches, recovery level, records, min_sum, q (x, y, z, w; NaN without an attitude),
sigma cross and roll (arcsec; NaN), the health counters (:data:`HEALTH_NAMES`), heap free
(bytes; 0 unknown), CRC-32 (``contract.crc32``) of everything before it."""
FIELDS = ("magic", "version", "state", "sequence", "time_ms", "frame_counter",
          "frame_timestamp", "epoch_us", "status", "link_code", "matches", "level",
          "n_records", "min_sum", "qx", "qy", "qz", "qw", "sigma_cross",
          "sigma_roll") + HEALTH_NAMES + ("heap_free", "crc")
BYTES = struct.calcsize(FORMAT)
HEALTH_AT = FIELDS.index(HEALTH_NAMES[0])
"""Index of the first health counter among the packed values."""


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
