"""A blob's features as a list with one slot per record field, in the contract's order: the
slot indices the streaming and wavefront engines accumulate into, taken from
``contract.RECORD_NAMES``, and the ``BlobRecord`` of such a list."""

from lodestar import contract as C

SLOTS = len(C.RECORD_NAMES)
"""Slots of a feature list (an engine may append its own after them)."""
N = C.RECORD_NAMES.index("n")
NSAT = C.RECORD_NAMES.index("nsat")
MOMENTS = tuple(C.RECORD_NAMES.index(name) for name in C.MOMENTS)
"""Slots of the moments, in ``contract.MOMENTS`` order."""
S0, SX, SY, SXX, SYY, SXY = MOMENTS
XMIN = C.RECORD_NAMES.index("xmin")
XMAX = C.RECORD_NAMES.index("xmax")
YMIN = C.RECORD_NAMES.index("ymin")
YMAX = C.RECORD_NAMES.index("ymax")
PEAK = C.RECORD_NAMES.index("peak")
FLAGS = C.RECORD_NAMES.index("flags")


def record(features):
    """The ``BlobRecord`` of a feature list (its first ``SLOTS`` slots)."""
    return C.BlobRecord(**dict(zip(C.RECORD_NAMES, features)))
