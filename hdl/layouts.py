"""Stream payloads, memory words and enums of the gateware, derived from ``lodestar.contract``.

Stream payloads, in pipeline order: ``pixel_layout`` (sensor -> threshold unit),
``lit_layout`` (threshold unit -> labeller), ``op_layout`` (labeller -> feature engine),
``record_layout`` and ``trailer_layout`` (detector -> packetizer).  A compact record has the
contract's field names with the frame's widths (``contract.moment_widths(pixel_bits)``, the
geometry's for the box); the packetizer zero-extends it to ``contract.RECORD_FIELDS``.  The
trailer carries the header fields a frame produces; ``magic``, ``version``, ``width``,
``height`` and ``pixel_bits`` are constants of the build.
"""

from amaranth.lib import data, enum

from lodestar import contract as C

TRAILER_NAMES = ("mode", "frame_counter", "timestamp", "flags", "threshold", "background",
                 "n_blobs",
                 "n_filtered", "dropped_records", "dropped_labels", "n_records")
"""Header fields the gateware produces per frame (the others are build constants)."""

FRAME_FLAGS_BITS = dict(C.HEADER_FIELDS)["flags"]
"""Width of a frame's status flags (``contract.FRAME_*``)."""

FRAME_TAG_BITS = 2
"""Width of the labeller's frame tag: ops of an aborted frame carry an old tag."""


class ThresholdMode(enum.Enum, shape=C.REGISTER_BY_NAME["mode"].bits):
    """The ``mode`` register (``contract.MODE_*``); any other value thresholds as fixed."""
    FIXED = C.MODE_FIXED
    GLOBAL = C.MODE_GLOBAL
    LOCAL = C.MODE_LOCAL


class PixelAction(enum.Enum, shape=2):
    """What the labeller's pixel stage does with the column's pixel (for waveforms)."""
    NONE = 0        # dark, or a run carrying on
    CONTINUE = 1    # a run starts under a previous-row node: its component continues
    BIRTH = 2       # a run starts over dark pixels: a new blob
    MERGE = 3       # a previous-row node of another component starts under the run


class PopAction(enum.Enum, shape=3):
    """What the labeller's pop stage does with a component whose last previous-row node
    ends at the column (for waveforms)."""
    NONE = 0        # no pop
    CARRY_ON = 1    # the current run belongs to it: it stays active
    MOVE_DOWN = 2   # the entry below is the same component: its information moves down
    PATCH_LAST = 3  # it has nodes in the current row: the last of them is marked last
    COMPLETE = 4    # a tracked blob is complete: its record is emitted
    DROP = 5        # an untracked blob is complete: counted in ``dropped_labels``


def check_frame(width, height, pixel_bits):
    """Raise ``ValueError`` unless ``width x height`` frames of ``pixel_bits`` pixels are
    within the contract (``contract.check_geometry``: the layouts' widths derive from them)."""
    C.check_geometry(width, height, pixel_bits)


def pixel_layout(pixel_bits):
    """Sensor pixel: ``sof`` on a frame's first pixel, ``eol`` on each line's last."""
    return data.StructLayout({"data": pixel_bits, "sof": 1, "eol": 1})


def lit_layout(width, height, pixel_bits):
    """Thresholded pixel: position, ``lit = p > T``, ``weight = max(p - B, 0)``, ``eof`` on
    the frame's last pixel."""
    return data.StructLayout({
        "data": pixel_bits, "x": C.bits_for(width - 1), "y": C.bits_for(height - 1),
        "lit": 1, "weight": pixel_bits, "eof": 1,
    })


def op_layout(width, height, pixel_bits, slots):
    """One labeller column decision for the feature engine (``hdl/features.py``); the slot
    ``wr`` writes follows a clock later on the engine's ``wr_slot``."""
    sb = C.bits_for(slots - 1)
    return data.StructLayout({
        "tag": FRAME_TAG_BITS, "pix": 1, "x": C.bits_for(width - 1),
        "y": C.bits_for(height - 1), "p": pixel_bits, "w": pixel_bits,
        "rd": 1, "rd_addr": sb, "complete": 1, "wr": 1,
    })


def record_fields(width, height, pixel_bits):
    """``[(name, bits)]`` of a compact record for ``width x height`` frames, contract order
    (``contract.record_fields``)."""
    return list(C.record_fields(width, height, pixel_bits))


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


def frame_registers_layout(names):
    """The registers ``names`` (``contract.REGISTERS``) latched for one frame."""
    return data.StructLayout({n: C.REGISTER_BY_NAME[n].bits for n in names})


# ---- memory words and registers internal to a unit ---------------------------------------

def delay_entry_layout(width, height, pixel_bits):
    """Threshold unit, local mode: a pixel waiting in the delay line for its window, with
    its column's window flags (computed when it is written, so that the read side decides
    the window's step from registers): ``row_start`` (x = 0), ``move_first`` and
    ``move_end`` (the columns where the window starts and stops moving)."""
    return data.StructLayout({"data": pixel_bits, "x": range(width), "y": range(height),
                              "eof": 1, "row_start": 1, "move_first": 1, "move_end": 1})


def local_pixel_layout(width, height, pixel_bits, sum_bits):
    """Threshold unit, local mode: a pixel entering the delay line (``LocalWindow``), with
    its position, ``sof``/``eof``, ``row_end`` (its line's last pixel) and the frame's
    running ``S1`` after it and before it (``sum_bits`` wide: a window's sum is their
    difference)."""
    return data.StructLayout({"data": pixel_bits, "x": range(width), "y": range(height),
                              "sof": 1, "eof": 1, "row_end": 1,
                              "sum_after": sum_bits, "sum_before": sum_bits})


def local_mean_layout(width, height, pixel_bits):
    """Threshold unit, local mode: a pixel leaving the delay line, with ``mean``, the mean
    of the other pixels of its window."""
    return data.StructLayout({"data": pixel_bits, "x": range(width), "y": range(height),
                              "eof": 1, "mean": pixel_bits})


def held_layout(x_bits, y_bits, pixel_bits):
    """Labeller: the input pixel held until its right neighbour arrives, the column decided
    next (in the virtual row, ``x`` is the column decided); ``first_row`` (``y == 0``) and
    ``last_col`` (``x == width - 1``) registered beside it."""
    return data.StructLayout({"valid": 1, "x": x_bits, "y": y_bits, "lit": 1,
                              "data": pixel_bits, "weight": pixel_bits, "first_row": 1,
                              "last_col": 1})


def node_flags_layout():
    """Labeller node: first/last node of its component in its row."""
    return data.StructLayout({"first": 1, "last": 1})


def node_label_layout(slot_bits):
    """Labeller node, meaningful on a first node: its component's feature slot."""
    return data.StructLayout({"slot": slot_bits, "tracked": 1})


def stack_entry_layout(slot_bits, node_bits):
    """Labeller stack entry: a previous-row component straddling the scan position.
    ``in_row``: it has nodes in the current row, the first at ``first_node`` and the last
    at ``last_node``; ``continues``: the entry below is the same component."""
    return data.StructLayout({"slot": slot_bits, "tracked": 1, "in_row": 1,
                              "first_node": node_bits, "last_node": node_bits,
                              "continues": 1})


def active_layout(slot_bits, node_bits):
    """Labeller: the current run's component.  ``has_slot``: ``slot`` is allocated;
    ``on_stack``: it is the top entry's component (previous-row nodes lie ahead)."""
    return data.StructLayout({"slot": slot_bits, "tracked": 1, "has_slot": 1, "in_row": 1,
                              "first_node": node_bits, "last_node": node_bits,
                              "on_stack": 1})
