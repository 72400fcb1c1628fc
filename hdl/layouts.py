"""Record and trailer layouts of the gateware, derived from ``lodestar.contract``.

The gateware stores blob records compactly: the moments have the widths of the frame's
pixel width (``contract.moment_widths(pixel_bits)``), the bounding box those of the frame's
geometry.  The packetizer zero-extends them into the contract's packet record
(``contract.RECORD_FIELDS``, 16-bit widths).  Field names are the contract's, so a record
converts to ``contract.BlobRecord`` by name.

The frame trailer carries the variable fields of the packet header
(``contract.HEADER_FIELDS``, same names and widths); ``magic``, ``version``, ``width``,
``height`` and ``pixel_bits`` are constants of the build.
"""

from amaranth.lib import data

from lodestar import contract as C

TRAILER_NAMES = ("mode", "frame_counter", "flags", "threshold", "background", "n_blobs",
                 "n_filtered", "dropped_records", "dropped_labels", "n_records")
"""Header fields the gateware produces per frame (the others are build constants)."""


def record_fields(width, height, pixel_bits):
    """``[(name, bits)]`` of a compact record for ``width x height`` frames, contract order."""
    moments = C.moment_widths(pixel_bits)
    xb, yb = C.bits_for(width - 1), C.bits_for(height - 1)
    count = C.bits_for(width * height)
    widths = {"n": count, "nsat": count, "xmin": xb, "xmax": xb, "ymin": yb, "ymax": yb,
              "peak": pixel_bits, "flags": C.bits_for(C.BLOB_FLAGS_DEFINED)}
    widths.update(moments)
    return [(name, widths[name]) for name in C.RECORD_NAMES]


def record_layout(width, height, pixel_bits):
    """Compact blob record as an Amaranth ``StructLayout``."""
    return data.StructLayout(dict(record_fields(width, height, pixel_bits)))


def trailer_fields():
    """``[(name, bits)]`` of the frame trailer: the header fields of ``TRAILER_NAMES``."""
    widths = dict(C.HEADER_FIELDS)
    return [(name, widths[name]) for name in TRAILER_NAMES]


def trailer_layout():
    """Frame trailer as an Amaranth ``StructLayout``."""
    return data.StructLayout(dict(trailer_fields()))
