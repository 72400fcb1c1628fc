"""Firmware status codes: small integers with a name and a one-line meaning.

Every firmware function that can fail on data (bytes from the FPGA, a star list, the star
database) returns one of these codes instead of raising; ``OK`` (0) is the only success.
``name(code)`` and ``meaning(code)`` turn a code into text for telemetry and logs.

Codes are grouped by decade so that modules can add theirs without renumbering::

     0       OK
     1 .. 19 packet decoding (``lodestar.firmware.packet``)
    20 .. 29 centroiding and camera model
    30 .. 39 star identification (``lodestar.firmware.starid.verify``, ``starid`` and the methods)
    40 .. 49 star database (``lodestar.firmware.database``)
    50 .. 59 generic

To add a code: define the constant below in its group and add a row to ``_TABLE``
(``tests/firmware/test_status.py`` checks that every constant has exactly one row and
that codes are unique).  The codes are `const()`: MicroPython folds them, and `_TABLE` with
them, into constants that a frozen image keeps in flash.  Pure Python, MicroPython-safe.
"""

try:
    from micropython import const
except ImportError:         # CPython
    def const(value):
        return value

OK = const(0)

# --- packet decoding (lodestar.firmware.packet) -----------------------------------------
PACKET_TRUNCATED = const(1)
PACKET_BAD_MAGIC = const(2)
PACKET_BAD_VERSION = const(3)
PACKET_BAD_LENGTH = const(4)
PACKET_BAD_CRC = const(5)
PACKET_BAD_HEADER = const(6)
PACKET_BAD_RECORD = const(7)
FRAME_INCOMPLETE = const(8)

# --- centroiding and camera model -------------------------------------------------------
TOO_FEW_STARS = const(20)
CAMERA_NOT_CONVERGED = const(21)
CAMERA_OUT_OF_VIEW = const(22)
SMEAR_TOO_LONG = const(23)
RATE_UNKNOWN = const(24)
RATE_CONTRADICTED = const(25)
IMPRECISE = const(26)

# --- star identification ----------------------------------------------------------------
NO_MATCH = const(30)
AMBIGUOUS = const(31)
BUDGET_EXHAUSTED = const(32)
MIRRORED = const(33)

# --- star database ----------------------------------------------------------------------
DATABASE_CORRUPT = const(40)
DATABASE_MISMATCH = const(41)
DATABASE_UNSUPPORTED = const(42)
DATABASE_IO = const(43)
DATABASE_BAD_LENGTH = const(44)
DATABASE_BAD_MAGIC = const(45)
DATABASE_BAD_VERSION = const(46)
DATABASE_BAD_LAYOUT = const(47)

# --- generic ----------------------------------------------------------------------------
BAD_INPUT = const(50)
INTERNAL_ERROR = const(51)
OUT_OF_MEMORY = const(52)

_TABLE = (
    (OK, "OK", "success"),
    (PACKET_TRUNCATED, "PACKET_TRUNCATED",
     "packet shorter than its header + CRC, or than its record count requires"),
    (PACKET_BAD_MAGIC, "PACKET_BAD_MAGIC", "packet does not start with contract.PACKET_MAGIC"),
    (PACKET_BAD_VERSION, "PACKET_BAD_VERSION", "packet version is not contract.PACKET_VERSION"),
    (PACKET_BAD_LENGTH, "PACKET_BAD_LENGTH",
     "packet longer than its record count requires (trailing bytes)"),
    (PACKET_BAD_CRC, "PACKET_BAD_CRC", "packet CRC-32 trailer does not match its contents"),
    (PACKET_BAD_HEADER, "PACKET_BAD_HEADER",
     "packet header field out of range or inconsistent (CRC was correct)"),
    (PACKET_BAD_RECORD, "PACKET_BAD_RECORD",
     "blob record field out of range or inconsistent (CRC was correct)"),
    (FRAME_INCOMPLETE, "FRAME_INCOMPLETE",
     "the gateware cut the frame short (FRAME_TRUNCATED, FRAME_TIMEOUT or FRAME_LINE_ERROR): "
     "its records are partial or misplaced"),
    (TOO_FEW_STARS, "TOO_FEW_STARS", "fewer usable stars than the algorithm needs"),
    (CAMERA_NOT_CONVERGED, "CAMERA_NOT_CONVERGED",
     "camera model: undistortion did not converge (pixel far outside the frame)"),
    (CAMERA_OUT_OF_VIEW, "CAMERA_OUT_OF_VIEW",
     "camera model: direction behind the camera or beyond the distortion fold radius"),
    (SMEAR_TOO_LONG, "SMEAR_TOO_LONG",
     "the body rate smears all but fewer than 3 stars beyond max_smear_px: no attitude"),
    (RATE_UNKNOWN, "RATE_UNKNOWN",
     "no gyro rate, too few stars to fit the body rate, and streaks that allow a rate "
     "whose shear the attitude cannot cover: no attitude"),
    (RATE_CONTRADICTED, "RATE_CONTRADICTED",
     "the frame's shear and streaks contradict the given gyro rate beyond their own "
     "uncertainty: no attitude"),
    (IMPRECISE, "IMPRECISE",
     "the 5-sigma bound of the solution's total error exceeds max_error_arcsec (default "
     "180 arcsec): its attitude and sigmas are "
     "in the result for diagnostics, not for use"),
    (NO_MATCH, "NO_MATCH", "no catalogue pattern matches the observed stars"),
    (AMBIGUOUS, "AMBIGUOUS", "several catalogue patterns match equally well"),
    (BUDGET_EXHAUSTED, "BUDGET_EXHAUSTED",
     "the pattern budget ran out before a verified identification"),
    (MIRRORED, "MIRRORED",
     "the stars match the sky only mirrored: flip the read-out (columns or rows)"),
    (DATABASE_CORRUPT, "DATABASE_CORRUPT",
     "star database failed its integrity check (header or payload CRC-32)"),
    (DATABASE_MISMATCH, "DATABASE_MISMATCH",
     "star database built for another camera (field of view)"),
    (DATABASE_UNSUPPORTED, "DATABASE_UNSUPPORTED",
     "star database lacks what the reader or the requested method needs"),
    (DATABASE_IO, "DATABASE_IO", "star database file cannot be opened or read"),
    (DATABASE_BAD_LENGTH, "DATABASE_BAD_LENGTH",
     "star database shorter than its header or not of the length its header says"),
    (DATABASE_BAD_MAGIC, "DATABASE_BAD_MAGIC", "star database does not start with b'LSDB'"),
    (DATABASE_BAD_VERSION, "DATABASE_BAD_VERSION",
     "star database format version or header size is not the one this reader reads"),
    (DATABASE_BAD_LAYOUT, "DATABASE_BAD_LAYOUT",
     "star database sections or header values inconsistent (CRC was correct)"),
    (BAD_INPUT, "BAD_INPUT", "argument of the wrong type or out of range"),
    (INTERNAL_ERROR, "INTERNAL_ERROR",
     "unexpected exception inside the firmware (a bug or a read error)"),
    (OUT_OF_MEMORY, "OUT_OF_MEMORY", "the heap could not hold what the call needed"),
)
"""``(code, name, meaning)`` of every status, in code order."""


def name(code):
    """The name of a status code (``"UNKNOWN(<code>)"`` for a code not in the table)."""
    for row in _TABLE:
        if row[0] == code:
            return row[1]
    return "UNKNOWN({})".format(code)


def meaning(code):
    """One-line meaning of a status code (``"unknown status"`` for a code not in the table)."""
    for row in _TABLE:
        if row[0] == code:
            return row[2]
    return "unknown status"


def codes():
    """All defined codes, ascending."""
    return tuple(row[0] for row in _TABLE)
