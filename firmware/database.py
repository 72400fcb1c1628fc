"""Star-identification database reader (flight side): one binary image, read by offset.

The layout is ``docs/stardb.md`` (built on the ground by ``lodestar.ground.database``).
``Database(buffer)`` reads ``bytes``, ``bytearray`` or a ``memoryview`` (a memory-mapped flash
region) with ``struct.unpack_from``; ``Database.open(path)`` reads a file by ``seek`` +
``readinto`` into one preallocated scratch buffer, never whole; ``Database.fram(spi, cs)``
reads the board's SPI F-RAM the same way, one ``READ`` transaction per read.  The validation
order and the ``DATABASE_*`` status of each failure: ``docs/firmware.md``, Database reader.
**Error policy**: the reader raises :class:`DatabaseError` (``status``, ``reason``); the flight
API calls :func:`load` or :func:`check`, which return ``(status, reason)``, so no exception
reaches the flight loop.  Every method of the contract's table is served
(:data:`SUPPORTED_METHODS`); the sections an image must carry follow from its ``methods``
mask and that table (:func:`required_sections`), and each section with its own header is
checked by one procedure (``lodestar.contract.stardb.KEYED_SECTIONS``).
Pure Python for CPython and MicroPython 1.27 (``struct``, ``binascii``, ``math``, ``array``).
"""

import math
import struct
from array import array

from lodestar.contract import stardb
from lodestar.contract.packet import crc32

from . import kvector
from . import status as S
from .emit import native

SUPPORTED_METHODS = stardb.METHOD_MASK
"""The methods this reader serves: every method of ``lodestar.contract.stardb.METHOD_TABLE``."""

# Status codes of DatabaseError / check() / load(): lodestar.firmware.status integers.
OK = S.OK
STATUSES = (S.OK, S.DATABASE_CORRUPT, S.DATABASE_MISMATCH, S.DATABASE_UNSUPPORTED,
            S.DATABASE_IO, S.DATABASE_BAD_LENGTH, S.DATABASE_BAD_MAGIC, S.DATABASE_BAD_VERSION,
            S.DATABASE_BAD_LAYOUT, S.OUT_OF_MEMORY)

_CHUNK = 512

_CELL_SCALE = 32767
"""Cell centres are held as ``array('h')`` of ``round(component * _CELL_SCALE)``: half the
heap of floats (the whole table is resident while the database is open)."""
_CELL_ERROR = 1e-4
"""Bound (rad) of the angle a rounded cell centre moves (``sqrt(3) / 2 / _CELL_SCALE`` = 2.6e-5,
with margin), added to a cone query's reach so no cell is missed."""
_FACE_RADIUS = math.atan(math.sqrt(2.0))
"""Angle (rad, 54.7 deg) from a cube face's centre to its corners: every cell centre of the
face lies within it, so a cone query skips a face whose centre is further than its reach plus
this (:meth:`Database.stars_in_cone`)."""
PAIR_BLOCK = 32
"""Most pair records one :meth:`Database.pair_stars` read returns."""
_PAIR_STARS_FORMAT = "<" + "2x2H" * PAIR_BLOCK
_SCRATCH_BYTES = max(stardb.HEADER_SIZE, PAIR_BLOCK * stardb.PAIR_SIZE)
"""A file source's read buffer: the header, or a block of pairs or of stars."""
STAR_BLOCK = _SCRATCH_BYTES // stardb.STAR_SIZE
"""Most star vectors one :meth:`Database.star_vectors` read returns."""
_STAR_VECTOR = "fff" + str(stardb.STAR_SIZE - 12) + "x"     # a star record's vector, then skip
_STAR_VECTORS_FORMAT = "<" + _STAR_VECTOR * STAR_BLOCK
_CELL_RANGE_FORMAT = "<" + stardb.CELL_FORMAT[1:] * 2        # two consecutive cell starts


class DatabaseError(Exception):
    """An image is corrupt or does not match: ``status`` (one of :data:`STATUSES`, a
    :mod:`lodestar.firmware.status` code) and ``reason`` (text); ``str(exc)`` is
    ``"<status name>: <reason>"``."""

    def __init__(self, status, reason):
        super().__init__(S.name(status) + ": " + reason)
        self.status = status
        self.reason = reason


# --------------------------------------------------------------------------------------
# Sky cells: a gnomonic cube, cells_per_face**2 cells per face
# --------------------------------------------------------------------------------------

@native
def cell_of(x, y, z, n):
    """Cell index of the direction ``(x, y, z)`` (any non-zero length) on the ``n x n``
    gnomonic cube: ``(face * n + iu) * n + iv``; face ``2a + (1 if negative)`` for major axis
    ``a`` (0 = x, 1 = y, 2 = z); ``u, v`` = the next two axes (cyclically) over ``|major|``."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        face, big, u, v = (0 if x >= 0 else 1), ax, y, z
    elif ay >= az:
        face, big, u, v = (2 if y >= 0 else 3), ay, z, x
    else:
        face, big, u, v = (4 if z >= 0 else 5), az, x, y
    iu = int((u / big + 1.0) * 0.5 * n)
    iv = int((v / big + 1.0) * 0.5 * n)
    iu = 0 if iu < 0 else (n - 1 if iu >= n else iu)
    iv = 0 if iv < 0 else (n - 1 if iv >= n else iv)
    return (face * n + iu) * n + iv


def cell_centre(c, n):
    """Unit vector ``(x, y, z)`` of the centre of cell ``c`` (inverse of :func:`cell_of`)."""
    face = c // (n * n)
    rest = c - face * n * n
    iu, iv = rest // n, rest % n
    u = (iu + 0.5) * 2.0 / n - 1.0
    v = (iv + 0.5) * 2.0 / n - 1.0
    s = -1.0 if face & 1 else 1.0
    a = face >> 1
    norm = math.sqrt(1.0 + u * u + v * v)
    if a == 0:
        return s / norm, u / norm, v / norm
    if a == 1:
        return v / norm, s / norm, u / norm
    return u / norm, v / norm, s / norm


_QUARTER = 0.25 * math.pi
"""Largest angle of a face coordinate's direction from the face centre (``u = tan(angle)``,
``|u| <= 1``)."""


@native
def cell_span(towards, along, radius, n):
    """``(lo, hi)``: the cell rows ``lo <= i < hi`` along one axis of a face (of ``n``) that
    can hold a direction within ``radius`` (rad) of the unit vector ``d``; ``towards``: the
    component of ``d`` along the face's outward axis, ``along``: along the face axis ``u``
    (or ``v``).  A face coordinate is ``u = tan(l)``, ``l`` the longitude about the other
    face axis, and a cone of radius ``r`` around a direction of longitude ``l0`` and
    latitude ``b`` spans ``l0 +- asin(sin r / cos b)`` (the whole circle when ``sin r >= cos
    b``); :data:`_CELL_ERROR` more on each side covers rounding (here and in the cells the
    ground assigned).  ``(0, 0)`` when the cone misses the face's rows."""
    h = math.sqrt(towards * towards + along * along)      # cos b
    reach = math.sin(radius) if radius < 0.5 * math.pi else 2.0
    if towards <= 0.0 or not reach < h:
        return 0, n
    centre = math.atan2(along, towards)
    spread = math.asin(reach / h) + _CELL_ERROR
    lo, hi = centre - spread, centre + spread
    if hi <= -_QUARTER or lo >= _QUARTER:
        return 0, 0
    i_lo = 0 if lo <= -_QUARTER else int((math.tan(lo) + 1.0) * 0.5 * n)
    i_hi = n if hi >= _QUARTER else int((math.tan(hi) + 1.0) * 0.5 * n) + 1
    return (i_lo if i_lo > 0 else 0), (i_hi if i_hi < n else n)


def n_cells(n):
    """Number of cells of the ``n x n`` cube grid."""
    return 6 * n * n


# --------------------------------------------------------------------------------------
# Byte sources: a buffer, or a file read by seek
# --------------------------------------------------------------------------------------

class _BufferSource:
    def __init__(self, buf):
        self.buf = buf if isinstance(buf, memoryview) else memoryview(buf)
        self.size = len(self.buf)

    def unpack(self, fmt, offset, size):
        return struct.unpack_from(fmt, self.buf, offset)

    def crc(self, start, stop):
        return crc32(self.buf[start:stop])

    def close(self):
        pass


class _FileSource:
    def __init__(self, f):
        self.f = f
        f.seek(0, 2)
        self.size = f.tell()
        self.scratch = bytearray(_SCRATCH_BYTES)
        self.mv = memoryview(self.scratch)

    def unpack(self, fmt, offset, size):
        f, mv = self.f, self.mv
        f.seek(offset)
        if f.readinto(mv[:size]) != size:
            raise DatabaseError(S.DATABASE_IO, "short read at offset " + str(offset))
        return struct.unpack_from(fmt, self.scratch, 0)

    def crc(self, start, stop):
        f = self.f
        chunk = bytearray(_CHUNK)
        mv = memoryview(chunk)
        f.seek(start)
        c = 0
        left = stop - start
        while left > 0:
            want = _CHUNK if left > _CHUNK else left
            got = f.readinto(mv[:want])
            if not got:
                raise DatabaseError(S.DATABASE_IO, "file ended early")
            c = crc32(mv[:got], c)
            left -= got
        return c

    def close(self):
        self.f.close()


FRAM_READ = 0x03
"""``READ`` opcode of the board's SPI F-RAM (a 4-Mbit FM25V-/CY15B104Q-class part): the
opcode, a 24-bit big-endian address, then data while CS stays low."""
FRAM_BYTES = 512 * 1024
"""The F-RAM's size (bytes): the end of any image read from it."""


class _FramSource:
    """The image at byte ``base`` of the SPI F-RAM on ``spi`` (``machine.SPI``: ``write``,
    ``readinto``) selected by ``cs`` (a ``machine.Pin``, active low): one ``READ``
    transaction per :meth:`unpack` into a scratch buffer as the file source's, the CRC in
    :data:`_CHUNK`-byte reads; nothing of the image is copied whole.  ``size`` (None: the
    header's ``image_size``), at most what lies between ``base`` and :data:`FRAM_BYTES`."""

    def __init__(self, spi, cs, base, size):
        self.spi = spi
        self.cs = cs
        self.base = base
        self.command = bytearray(4)
        self.command[0] = FRAM_READ
        self.scratch = bytearray(_SCRATCH_BYTES)
        self.mv = memoryview(self.scratch)
        if not 0 <= base < FRAM_BYTES:
            raise DatabaseError(S.DATABASE_IO, "F-RAM base " + str(base) + " outside 0.." +
                                str(FRAM_BYTES - 1))
        if size is None:
            self.size = stardb.HEADER_SIZE      # enough to read the header's image size
            size = self.unpack(stardb.HEADER_FORMAT, 0, stardb.DIRECTORY_OFFSET)[
                stardb.HEADER_FIELDS.index("image_size")]
        self.size = min(size, FRAM_BYTES - base)

    def _read(self, offset, view):
        address = self.base + offset
        command = self.command
        command[1] = (address >> 16) & 0xFF
        command[2] = (address >> 8) & 0xFF
        command[3] = address & 0xFF
        cs = self.cs
        try:
            cs.value(0)
            try:
                self.spi.write(command)
                self.spi.readinto(view, 0)
            finally:
                cs.value(1)
        except OSError as exc:
            raise DatabaseError(S.DATABASE_IO, "F-RAM read at " + str(address) + " failed (" +
                                repr(exc) + ")") from None

    def unpack(self, fmt, offset, size):
        if offset + size > self.size:
            raise DatabaseError(S.DATABASE_IO, "read past the image at offset " + str(offset))
        self._read(offset, self.mv[:size])
        return struct.unpack_from(fmt, self.scratch, 0)

    def crc(self, start, stop):
        chunk = bytearray(_CHUNK)
        mv = memoryview(chunk)
        c = 0
        while start < stop:
            want = _CHUNK if stop - start > _CHUNK else stop - start
            self._read(start, mv[:want])
            c = crc32(mv[:want], c)
            start += want
        return c

    def close(self):
        pass


# --------------------------------------------------------------------------------------
# The reader
# --------------------------------------------------------------------------------------

def _finite_positive(x):
    return x == x and 0.0 < x < 1e30


def required_sections(methods):
    """The section ids an image with the ``methods`` mask must carry (the contract's
    :data:`~lodestar.contract.stardb.METHOD_TABLE`; repeats possible)."""
    out = []
    for entry in stardb.METHOD_TABLE:
        if methods & entry[1]:
            out.extend(entry[3])
    return out


class Database:
    """A validated star-identification database image.

    ``Database(buffer)`` over bytes-like memory or :meth:`open` over a file; both raise
    :class:`DatabaseError` on any corruption or mismatch.  ``expected_fov_h`` (rad), when
    given, must match the image's horizontal FOV to ``fov_tolerance`` (relative), else
    ``FOV_MISMATCH``.  Header values are attributes named as in :data:`stardb.HEADER_FIELDS`
    (angles in radians); ``sections`` is the list of ``(offset, length)``.
    """

    def __init__(self, buffer=None, expected_fov_h=None, fov_tolerance=0.02, _source=None):
        src = _source if _source is not None else _BufferSource(buffer)
        self._src = src
        try:
            self._validate(expected_fov_h, fov_tolerance)
            self._cells = self._cell_centres()
        except DatabaseError:
            raise
        except MemoryError:
            raise DatabaseError(S.OUT_OF_MEMORY, "out of heap opening the database") from None
        except Exception as exc:     # struct errors on a short or odd buffer
            raise DatabaseError(S.DATABASE_BAD_LAYOUT,
                                "unreadable image (" + repr(exc) + ")") from None

    @classmethod
    def open(cls, path, expected_fov_h=None, fov_tolerance=0.02):
        """Open the image file ``path`` (kept open; call :meth:`close`)."""
        try:
            f = open(path, "rb")
        except OSError as exc:
            raise DatabaseError(S.DATABASE_IO,
                                "cannot open " + str(path) + " (" + repr(exc) + ")") from None
        try:
            return cls(expected_fov_h=expected_fov_h, fov_tolerance=fov_tolerance,
                       _source=_FileSource(f))
        except Exception:
            f.close()
            raise

    @classmethod
    def fram(cls, spi, cs, base=0, size=None, expected_fov_h=None, fov_tolerance=0.02):
        """The image at byte ``base`` of the board's SPI F-RAM (:data:`FRAM_READ`) on
        ``spi`` with chip select ``cs``; ``size`` (bytes, None: the header's image size).
        Every read is one bus transaction when it is needed, as a file's; a bus ``OSError``
        is ``DATABASE_IO``."""
        return cls(expected_fov_h=expected_fov_h, fov_tolerance=fov_tolerance,
                   _source=_FramSource(spi, cs, base, size))

    def close(self):
        """Release the file of :meth:`open` (no-op for buffers)."""
        self._src.close()

    # ---- validation ----------------------------------------------------------------

    def _validate(self, expected_fov_h, fov_tolerance):
        src = self._src
        if src.size < stardb.HEADER_SIZE:
            raise DatabaseError(S.DATABASE_BAD_LENGTH, "image of " + str(src.size) +
                                " bytes is shorter than the header")
        values = src.unpack(stardb.HEADER_FORMAT, 0, stardb.DIRECTORY_OFFSET)
        for name, value in zip(stardb.HEADER_FIELDS, values):
            setattr(self, name, value)
        if self.magic != stardb.MAGIC:
            raise DatabaseError(S.DATABASE_BAD_MAGIC, "magic " + repr(self.magic) + " is not " +
                                repr(stardb.MAGIC))
        if self.version != stardb.VERSION:
            raise DatabaseError(S.DATABASE_BAD_VERSION, "format version " + str(self.version) +
                                " (this reader reads " + str(stardb.VERSION) + ")")
        if self.header_size != stardb.HEADER_SIZE:
            raise DatabaseError(S.DATABASE_BAD_VERSION, "header size " + str(self.header_size))
        if src.crc(0, stardb.HEADER_CRC_OFFSET) != src.unpack("<I", stardb.HEADER_CRC_OFFSET, 4)[0]:
            raise DatabaseError(S.DATABASE_CORRUPT, "header CRC-32 mismatch")
        if self.image_size != src.size:
            raise DatabaseError(S.DATABASE_BAD_LENGTH, "image is " + str(src.size) +
                                " bytes, header says " + str(self.image_size))
        if src.crc(stardb.HEADER_SIZE, src.size) != self.payload_crc:
            raise DatabaseError(S.DATABASE_CORRUPT, "payload CRC-32 mismatch")
        self.sections = []
        for i in range(stardb.N_SECTIONS):
            self.sections.append(src.unpack("<II", stardb.DIRECTORY_OFFSET + 8 * i, 8))
        self._check_layout()
        if expected_fov_h is not None:
            if abs(self.fov_h - expected_fov_h) > fov_tolerance * expected_fov_h:
                raise DatabaseError(S.DATABASE_MISMATCH, "database horizontal FOV " +
                                    str(self.fov_h) + " rad, camera " + str(expected_fov_h))

    def _check_layout(self):
        def bad(reason):
            raise DatabaseError(S.DATABASE_BAD_LAYOUT, reason)

        if self.methods == 0 or self.methods & ~stardb.METHOD_MASK:
            bad("unknown method mask " + str(self.methods))
        if not self.methods & SUPPORTED_METHODS:
            raise DatabaseError(S.DATABASE_UNSUPPORTED, "method mask " + str(self.methods) +
                                " has nothing this reader serves")
        if self.star_record_size != stardb.STAR_SIZE:
            bad("star record size " + str(self.star_record_size))
        for name in ("fov_h", "fov_v", "fov_diag", "cell_radius"):
            if not _finite_positive(getattr(self, name)) or getattr(self, name) > math.pi:
                bad(name + " is not an angle in (0, pi]")
        if not 0 < self.n_stars <= stardb.MAX_STARS or self.n_pattern_stars > self.n_stars:
            bad("star counts " + str(self.n_stars) + "/" + str(self.n_pattern_stars))
        if not 1 <= self.cells_per_face <= 64:
            bad("cells_per_face " + str(self.cells_per_face))
        expected = {stardb.SEC_STARS: self.n_stars * stardb.STAR_SIZE,
                    stardb.SEC_CELLS: (n_cells(self.cells_per_face) + 1) * 2}
        required = required_sections(self.methods)
        if stardb.SEC_PAIRS in required:         # the pair table's values are header fields
            if self.n_pairs < 1 or self.kv_bins < 1:
                bad("pair table without pairs or k-vector bins")
            if not (_finite_positive(self.key_step) and _finite_positive(self.kv_m)) or \
                    self.kv_q != self.kv_q:
                bad("key step or k-vector line not finite and positive")
            expected[stardb.SEC_PAIRS] = self.n_pairs * stardb.PAIR_SIZE
            expected[stardb.SEC_KVECTOR] = (self.kv_bins + 1) * 4
        spans = []
        for sec in range(stardb.N_SECTIONS):
            offset, length = self.sections[sec]
            if length == 0:
                if sec in required:
                    bad("section " + stardb.SECTION_NAMES[sec] + " is missing")
                continue
            if offset < stardb.HEADER_SIZE or offset % stardb.SECTION_ALIGN or \
                    offset + length > self.image_size:
                bad("section " + stardb.SECTION_NAMES[sec] + " lies outside the image")
            if sec in expected and length != expected[sec]:
                bad("section " + stardb.SECTION_NAMES[sec] + " is " + str(length) +
                    " bytes, expected " + str(expected[sec]))
            spans.append((offset, offset + length))
        spans.sort()
        for i in range(1, len(spans)):
            if spans[i][0] < spans[i - 1][1]:
                bad("sections overlap")
        self._stars_off = self.sections[stardb.SEC_STARS][0]
        self._cells_off = self.sections[stardb.SEC_CELLS][0]
        self._pairs_off = self.sections[stardb.SEC_PAIRS][0]
        self._kv_off = self.sections[stardb.SEC_KVECTOR][0]
        nc = n_cells(self.cells_per_face)
        if self._cell_start(0) != 0 or self._cell_start(nc) != self.n_stars:
            bad("cell index does not span the star table")
        for spec in stardb.KEYED_SECTIONS:
            setattr(self, spec[1] + "n", 0)
            if spec[0] in required:
                self._check_keyed(spec, bad)

    def _check_keyed(self, spec, bad):
        """Check a section of :data:`~lodestar.contract.stardb.KEYED_SECTIONS`: its header
        (fields set as attributes ``prefix + name``), the values of its method
        (:data:`_KEYED_VALUES`), its length, its sorted keys and k-vector; sets the offsets
        ``_<prefix>off`` (records) and ``_<prefix>kv_off`` (k-vector)."""
        sec, prefix, magic, fmt, size, fields, key_format = spec
        name = stardb.SECTION_NAMES[sec]
        offset, length = self.sections[sec]
        if length < size:
            bad("section " + name + " is shorter than its header")
        values = self._src.unpack(fmt, offset, size)
        if values[0] != magic:
            raise DatabaseError(S.DATABASE_UNSUPPORTED, "section " + name + " format " +
                                repr(values[0]) + " is not " + repr(magic))
        for field, value in zip(fields[1:], values[1:]):
            setattr(self, prefix + field, value)
        record_size = _KEYED_VALUES[sec](self, bad)
        n, kv_bins = getattr(self, prefix + "n"), getattr(self, prefix + "kv_bins")
        if n < 1 or kv_bins < 1:
            bad("section " + name + " without records or k-vector bins")
        body = n * record_size
        if length != size + body + (-body) % stardb.SECTION_ALIGN + 4 * (kv_bins + 1):
            bad("section " + name + " is " + str(length) + " bytes, its header implies otherwise")
        off = offset + size
        kv_off = off + body + (-body) % stardb.SECTION_ALIGN
        setattr(self, "_" + prefix + "off", off)
        setattr(self, "_" + prefix + "kv_off", kv_off)
        src = self._src
        kv_m, kv_q = getattr(self, prefix + "kv_m"), getattr(self, prefix + "kv_q")
        if not (_finite_positive(kv_m) and kv_q == kv_q and abs(kv_q) < 1e30):
            bad(name + " k-vector line not finite")
        if src.unpack(stardb.KV_FORMAT, kv_off, 4)[0] > n or \
                src.unpack(stardb.KV_FORMAT, kv_off + 4 * kv_bins, 4)[0] != n:
            bad(name + " k-vector does not span its records")
        key_size = struct.calcsize(key_format)
        if src.unpack(key_format, off, key_size)[0] > \
                src.unpack(key_format, off + (n - 1) * record_size, key_size)[0]:
            bad(name + " records are not sorted")

    def _triangle_values(self, bad):
        """The triangle section's own values; returns its record size."""
        for name in ("tri_area_step", "tri_moment_step", "tri_max_side"):
            if not _finite_positive(getattr(self, name)) or getattr(self, name) > 4.0:
                bad(name + " not finite and positive")
        return stardb.TRI_RECORD_SIZE

    def _hash_values(self, bad):
        """The hash section's own values; returns its record size (sets the record format)."""
        g = self.hash_group_size
        if g not in stardb.HASH_GROUP_SIZES or self.hash_flags & ~stardb.HASH_FLAG_DISTANCE:
            raise DatabaseError(S.DATABASE_UNSUPPORTED, "hash group size " + str(g) +
                                " or flags " + str(self.hash_flags) + " not served")
        for name in ("hash_coord_bucket", "hash_dist_bucket", "hash_max_diameter"):
            if not _finite_positive(getattr(self, name)) or getattr(self, name) > 4.0:
                bad(name + " not finite and positive")
        if not (abs(self.hash_coord_lo) < 4.0 and 0.0 <= self.hash_min_diameter <
                self.hash_max_diameter):
            bad("hash coordinate grid or diameters out of range")
        nd = self.hash_dist_buckets if self.hash_flags & stardb.HASH_FLAG_DISTANCE else 1
        if self.hash_coord_buckets < 1 or nd < 1 or \
                self.hash_coord_buckets ** (2 * (g - 2)) * nd > stardb.HASH_MAX_CODE:
            bad("hash bucket grid too large")
        self._hash_record_size = 4 + 2 * g
        self._hash_format = "<I" + "H" * g
        return self._hash_record_size

    def _cell_centres(self):
        n = self.cells_per_face
        out = array("h", range(3 * n_cells(n)))      # its final size (overwritten below)
        for c in range(n_cells(n)):
            x, y, z = cell_centre(c, n)
            out[3 * c] = int(round(x * _CELL_SCALE))
            out[3 * c + 1] = int(round(y * _CELL_SCALE))
            out[3 * c + 2] = int(round(z * _CELL_SCALE))
        return out

    # ---- stars -------------------------------------------------------------------------

    def star_vector(self, i):
        """Inertial unit vector ``(x, y, z)`` of star ``i`` (float32 precision)."""
        r = self._src.unpack("<fff", self._stars_off + i * stardb.STAR_SIZE, 12)
        return r[0], r[1], r[2]

    def star_vectors(self, start, n=STAR_BLOCK):
        """The vectors of stars ``start, start + 1, ...`` as one flat tuple ``(x, y, z, x,
        ...)``: ``n`` of them, at most :data:`STAR_BLOCK` (fewer at the end of the table),
        in one read.  Unpacking costs per value read, and a shorter format costs a slice
        of this one: on the Cortex-M4F build a whole block of 12 unpacks faster than 11."""
        left = self.n_stars - start
        if n > left:
            n = left
        if n >= STAR_BLOCK:
            return self._src.unpack(_STAR_VECTORS_FORMAT,
                                    self._stars_off + start * stardb.STAR_SIZE,
                                    STAR_BLOCK * stardb.STAR_SIZE)
        return self._src.unpack(_STAR_VECTORS_FORMAT[:1 + len(_STAR_VECTOR) * n],
                                self._stars_off + start * stardb.STAR_SIZE,
                                n * stardb.STAR_SIZE)

    def _star_word(self, i):
        return self._src.unpack("<HH", self._stars_off + i * stardb.STAR_SIZE + 12, 4)

    def star_hip(self, i):
        """Hipparcos number of star ``i``."""
        lo, word = self._star_word(i)
        return lo | ((word & 1) << 16)

    def star_mag(self, i):
        """V magnitude of star ``i`` (0.01 mag resolution)."""
        return ((self._star_word(i)[1] >> 1) & 0x7FF) / stardb.MAG_SCALE - stardb.MAG_OFFSET

    def star_flags(self, i):
        """Flag bits of star ``i`` (:data:`stardb.STAR_FLAG_PATTERN`)."""
        return self._star_word(i)[1] >> 12

    def star(self, i):
        """``(x, y, z, hip, mag, flags)`` of star ``i``."""
        x, y, z, lo, word = self._src.unpack(stardb.STAR_FORMAT,
                                             self._stars_off + i * stardb.STAR_SIZE,
                                             stardb.STAR_SIZE)
        mag = ((word >> 1) & 0x7FF) / stardb.MAG_SCALE - stardb.MAG_OFFSET
        return (x, y, z, lo | ((word & 1) << 16), mag, word >> 12)

    def _cell_start(self, c):
        return self._src.unpack(stardb.CELL_FORMAT, self._cells_off + 2 * c, 2)[0]

    def cell_range(self, c):
        """``(start, stop)`` star indices of sky cell ``c`` (stars are stored by cell)."""
        return self._src.unpack(_CELL_RANGE_FORMAT, self._cells_off + 2 * c, 4)

    @native
    def stars_in_cone(self, d, radius, out=None, vecs=None):
        """Indices of the stars within ``radius`` (rad) of the unit vector ``d``, appended
        to ``out`` (a new list when ``None``) in table order; ``vecs``: a list to which
        each such star's vector ``x, y, z`` is appended as well (one read of the table for
        both; a list, as MicroPython grows an ``array`` 8 entries at a time, each move
        leaving a hole).  Only the cells of each face's rows and columns the cone can reach
        (:func:`cell_span`) are tested, then each cell's centre; the cells of a row that
        pass are consecutive in the table (stars are stored by cell), so a row's stars are
        read as one run of whole blocks (:meth:`_cone_run`) and each is tested."""
        if out is None:
            out = []
        dx, dy, dz = d
        cos_r = math.cos(radius) if radius < math.pi else -2.0
        reach = radius + self.cell_radius + _CELL_ERROR
        cos_reach = _CELL_SCALE * math.cos(reach) if reach < math.pi else -2.0 * _CELL_SCALE
        far = reach + _FACE_RADIUS + _CELL_ERROR
        cos_face = math.cos(far) if far < math.pi else -2.0
        cells = self._cells
        n = self.cells_per_face
        view = getattr(self._src, "buf", None)     # a buffer: unpacked in place
        cells_off = self._cells_off
        for face in range(6):           # cells are stored face by face (cell_of)
            a = face >> 1
            towards = -d[a] if face & 1 else d[a]
            if towards < cos_face:
                continue                # the whole face is out of reach
            u_lo, u_hi = cell_span(towards, d[(a + 1) % 3], radius, n)
            v_lo, v_hi = cell_span(towards, d[(a + 2) % 3], radius, n)
            for iu in range(u_lo, u_hi):
                row = (face * n + iu) * n
                first = last = -1       # the row's first and last cell within reach
                for c in range(row + v_lo, row + v_hi):
                    j = 3 * c
                    if cells[j] * dx + cells[j + 1] * dy + cells[j + 2] * dz >= cos_reach:
                        if first < 0:
                            first = c
                        last = c
                if first < 0:
                    continue
                if view is not None:
                    a = struct.unpack_from(stardb.CELL_FORMAT, view, cells_off + 2 * first)[0]
                    b = struct.unpack_from(stardb.CELL_FORMAT, view, cells_off + 2 * last + 2)[0]
                else:
                    a, b = self._cell_start(first), self._cell_start(last + 1)
                self._cone_run(a, b, dx, dy, dz, cos_r, out, vecs, view)
        return out

    @native
    def _cone_run(self, a, b, dx, dy, dz, cos_r, out, vecs, view):
        """The stars ``a <= i < b`` within ``cos_r`` of ``d``, appended to ``out`` (and their
        vectors to ``vecs``, unless None).  Read a whole block at a time while one fits in
        the table (unpacking the few records past ``b`` costs less than a shorter format),
        from ``view`` (the database's buffer, or None: through its source) without the
        layers of :meth:`star_vectors` (a tenth of a query on the Cortex-M4F build)."""
        whole = self.n_stars - STAR_BLOCK
        off = self._stars_off
        while a < b:
            n = b - a if b - a < STAR_BLOCK else STAR_BLOCK
            if a > whole:
                v = self.star_vectors(a, n)
            elif view is not None:
                v = struct.unpack_from(_STAR_VECTORS_FORMAT, view, off + a * stardb.STAR_SIZE)
            else:
                v = self.star_vectors(a)
            j = 0
            for k in range(n):
                x = v[j]
                y = v[j + 1]
                z = v[j + 2]
                if x * dx + y * dy + z * dz >= cos_r:
                    out.append(a + k)
                    if vecs is not None:
                        vecs.append(x)
                        vecs.append(y)
                        vecs.append(z)
                j += 3
            a += n

    # ---- pairs ----------------------------------------------------------------------

    def pair(self, i):
        """Star indices ``(a, b)``, ``a < b``, of pair ``i`` (pairs sorted by angle)."""
        r = self._src.unpack(stardb.PAIR_FORMAT, self._pairs_off + i * stardb.PAIR_SIZE,
                             stardb.PAIR_SIZE)
        return r[1], r[2]

    def pair_record(self, i):
        """``(key, a, b)`` of pair ``i``: its angle is ``key * key_step`` rad."""
        return self._src.unpack(stardb.PAIR_FORMAT, self._pairs_off + i * stardb.PAIR_SIZE,
                                stardb.PAIR_SIZE)

    def pair_stars(self, start, n):
        """Star indices of the ``n`` pairs ``start .. start + n - 1`` (``1 <= n <=
        PAIR_BLOCK``) as one flat tuple ``(a, b, a, b, ...)``: one read instead of ``n``."""
        fmt = _PAIR_STARS_FORMAT if n == PAIR_BLOCK else "<" + "2x2H" * n
        return self._src.unpack(fmt, self._pairs_off + start * stardb.PAIR_SIZE,
                                n * stardb.PAIR_SIZE)

    def pair_key(self, i):
        """Integer angle key of pair ``i`` (ascending with ``i``)."""
        return self._src.unpack("<H", self._pairs_off + i * stardb.PAIR_SIZE, 2)[0]

    def pair_angle(self, i):
        """Inter-star angle of pair ``i`` as stored, rad (``key * key_step``)."""
        return self.pair_key(i) * self.key_step

    def _kv_at(self, j):
        return self._src.unpack(stardb.KV_FORMAT, self._kv_off + 4 * j, 4)[0]

    def pairs_in_range(self, lo, hi):
        """``(start, stop)``: the pairs ``start <= i < stop`` are exactly those whose stored
        angle key ``k`` satisfies ``lo / key_step <= k <= hi / key_step`` (angles in rad),
        found through the k-vector (no scan)."""
        s = self.key_step
        return kvector.query(lo / s, hi / s, self.kv_m, self.kv_q, self.kv_bins,
                             self._kv_at, self.pair_key, self.n_pairs)

    # ---- triangles (method 'triangle') --------------------------------------------

    def has_method(self, bit):
        """True when the image advertises (and this reader validated) method ``bit``."""
        return bool(self.methods & bit)

    def triangle_record(self, i):
        """``(area_key, moment_key, s0, s1, s2)`` of triangle ``i``: its (chord) area is
        ``area_key * tri_area_step`` and polar moment ``moment_key * tri_moment_step``;
        ``s0, s1, s2`` are the stars opposite its shortest, middle and longest side."""
        return self._src.unpack(stardb.TRI_RECORD_FORMAT,
                                self._tri_off + i * stardb.TRI_RECORD_SIZE,
                                stardb.TRI_RECORD_SIZE)

    def triangle_area_key(self, i):
        """Integer area key of triangle ``i`` (ascending with ``i``)."""
        return self._src.unpack("<H", self._tri_off + i * stardb.TRI_RECORD_SIZE, 2)[0]

    def _tri_kv_at(self, j):
        return self._src.unpack(stardb.KV_FORMAT, self._tri_kv_off + 4 * j, 4)[0]

    def triangles_in_range(self, lo, hi):
        """``(start, stop)``: exactly the triangles whose area key ``k`` satisfies
        ``lo / tri_area_step <= k <= hi / tri_area_step`` (areas in rad^2), by k-vector."""
        s = self.tri_area_step
        return kvector.query(lo / s, hi / s, self.tri_kv_m, self.tri_kv_q, self.tri_kv_bins,
                             self._tri_kv_at, self.triangle_area_key, self.tri_n)

    # ---- hash groups (method 'hashing') ---------------------------------------------

    def hash_record(self, i):
        """``(code, A, B, C[, D])`` of hash group ``i`` (stars in canonical order)."""
        return self._src.unpack(self._hash_format, self._hash_off + i * self._hash_record_size,
                                self._hash_record_size)

    def hash_code(self, i):
        """Bucket code of hash group ``i`` (ascending with ``i``)."""
        return self._src.unpack("<I", self._hash_off + i * self._hash_record_size, 4)[0]

    def _hash_kv_at(self, j):
        return self._src.unpack(stardb.KV_FORMAT, self._hash_kv_off + 4 * j, 4)[0]

    def hash_bucket(self, code):
        """``(start, stop)``: the hash groups of bucket ``code`` (by k-vector)."""
        return kvector.query(code, code, self.hash_kv_m, self.hash_kv_q, self.hash_kv_bins,
                             self._hash_kv_at, self.hash_code, self.hash_n)

    def info(self):
        """The header values as a dict (for telemetry and the ground tools); the triangle
        and hash section headers as dicts ``"triangles"`` and ``"hash"`` when served."""
        out = {}
        for name in stardb.HEADER_FIELDS:
            out[name] = getattr(self, name)
        out["sections"] = list(self.sections)
        required = required_sections(self.methods)
        for sec, prefix, _, _, _, fields, _ in stardb.KEYED_SECTIONS:
            if sec in required:
                out[stardb.SECTION_NAMES[sec]] = dict((name, getattr(self, prefix + name))
                                                 for name in fields[1:])
        return out


_KEYED_VALUES = {stardb.SEC_TRIANGLES: Database._triangle_values,
                 stardb.SEC_HASH: Database._hash_values}
"""The checks of the values of each keyed section's method (:meth:`Database._check_keyed`)."""


def check(buffer):
    """Validate an image in memory: ``(OK, "")`` or ``(status, reason)``; never raises."""
    try:
        Database(buffer)
    except DatabaseError as exc:
        return exc.status, exc.reason
    return OK, ""


def load(source, expected_fov_h=None, fov_tolerance=0.02):
    """Flight entry point: ``(database, OK, "")`` or ``(None, status, reason)`` (status codes
    of :mod:`lodestar.firmware.status`).

    ``source`` is a bytes-like image or a file path (``str``); never raises.
    """
    try:
        if isinstance(source, str):
            db = Database.open(source, expected_fov_h, fov_tolerance)
        else:
            db = Database(source, expected_fov_h, fov_tolerance)
    except DatabaseError as exc:
        return None, exc.status, exc.reason
    return db, OK, ""
