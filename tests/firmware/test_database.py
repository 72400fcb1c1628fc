"""Tests of ``lodestar.firmware.database``: buffer and file readers agree, every corrupted
byte is refused with a clear status, mismatches (version, magic, method, FOV, layout) are
named, cone queries equal brute force, and the module keeps to the firmware rules."""

import functools
import io
import math
import pathlib
import struct

import numpy as np
import pytest

from lodestar.contract import stardb
from lodestar.firmware import database
from lodestar.firmware import status as S
from lodestar.firmware.database import STAR_BLOCK, Database, DatabaseError, cell_span, check, load
from lodestar.ground.database import build_database
from lodestar.regress import fram
from lodestar.sim.presets import load_preset
from tests.firmware.db_images import reseal, status_of

FIRMWARE = pathlib.Path(database.__file__).parent


@functools.lru_cache(maxsize=None)
def tiny_image():
    """~8 KB image (V <= 3.0): small enough to corrupt every byte."""
    return build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=3.0, cells_per_face=2)


@functools.lru_cache(maxsize=None)
def estcube2_image():
    return build_database(camera=load_preset("estcube2"), mag_limit=6.0)




# --------------------------------------------------------------------------------------
# Round trip
# --------------------------------------------------------------------------------------

def all_records(db):
    return ([db.star(i) for i in range(db.n_stars)],
            [db.pair_record(i) for i in range(db.n_pairs)],
            [db.cell_range(c) for c in range(database.n_cells(db.cells_per_face))])


@pytest.mark.parametrize("wrap", [bytes, bytearray, memoryview])
def test_buffer_types(wrap):
    image = tiny_image()
    db = Database(wrap(image))
    assert db.info()["image_size"] == len(image)
    assert all_records(db) == all_records(Database(image))


def _both_readers(image, tmp_path):
    """``(Database(image), Database.open(a file of image))``; the caller closes the file."""
    path = tmp_path / "db.bin"
    path.write_bytes(image)
    return Database(image), Database.open(str(path))


def test_file_reader_equals_buffer_reader(tmp_path):
    mem, f = _both_readers(tiny_image(), tmp_path)
    try:
        assert all_records(f) == all_records(mem)
        assert f.info() == mem.info()
        assert f.pairs_in_range(0.1, 0.12) == mem.pairs_in_range(0.1, 0.12)
        assert f.stars_in_cone((0.0, 0.0, 1.0), 0.3) == mem.stars_in_cone((0.0, 0.0, 1.0), 0.3)
    finally:
        f.close()


def test_header_values():
    db = Database(estcube2_image())
    h, v, d = (math.radians(a) for a in load_preset("estcube2").fov_deg())
    assert math.isclose(db.fov_h, h, rel_tol=1e-6) and math.isclose(db.fov_v, v, rel_tol=1e-6)
    assert math.isclose(db.fov_diag, d, rel_tol=1e-6)
    assert math.isclose(db.pair_max_angle, d, rel_tol=1e-6)
    assert db.key_step * 65535 >= db.pair_max_angle
    assert db.mag_limit == 6.0 and db.version == 1 and db.methods == stardb.METHOD_PYRAMID
    assert 0 < db.n_pattern_stars < db.n_stars
    assert db.pair(0) == db.pair_record(0)[1:]
    assert db.pair_angle(db.n_pairs - 1) <= db.pair_max_angle + db.key_step


def test_stars_in_cone_equals_brute_force():
    db = Database(estcube2_image())
    vec = np.array([db.star_vector(i) for i in range(db.n_stars)])
    rng = np.random.default_rng(3)
    for _ in range(40):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        radius = rng.uniform(0.01, 0.5)
        got = sorted(db.stars_in_cone(tuple(d), radius))
        expected = np.flatnonzero(vec @ d >= np.float64(math.cos(radius)))
        assert got == expected.tolist()
    assert len(db.stars_in_cone((0.0, 0.0, 1.0), 4.0)) == db.n_stars
    # at the cube's corners, edges and face centres, where the face test decides
    r3, r2 = 1.0 / math.sqrt(3.0), 1.0 / math.sqrt(2.0)
    for d in [(r3, r3, r3), (-r3, -r3, r3), (r3, -r3, -r3), (r2, r2, 0.0), (0.0, -r2, r2),
              (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)]:
        for radius in (0.02, 0.2, 0.6):
            got = sorted(db.stars_in_cone(d, radius))
            expected = np.flatnonzero(vec @ np.array(d) >= np.float64(math.cos(radius)))
            assert got == expected.tolist(), (d, radius)


def test_stars_in_cone_spans_miss_no_star():
    """The cells a query tests (:func:`cell_span` per face axis) hold every star of the cone
    at any direction and radius, face edges and corners included; ``vecs`` gets each found
    star's vector."""
    db = Database(estcube2_image())
    vec = np.array([db.star_vector(i) for i in range(db.n_stars)])
    rng = np.random.default_rng(11)
    for k in range(300):
        d = rng.normal(size=3)
        if k % 3 == 0:                  # near an edge or a corner of the cube
            d[rng.integers(3)] = np.sign(d[0]) * abs(d[1])
        d /= np.linalg.norm(d)
        radius = float(np.exp(rng.uniform(math.log(0.003), math.log(1.6))))
        vecs = []
        got = db.stars_in_cone(tuple(d), radius, vecs=vecs)
        expected = np.flatnonzero(vec @ d >= np.float64(math.cos(radius)))
        assert sorted(got) == expected.tolist() and got == sorted(got), (d, radius)
        assert [tuple(vecs[3 * j:3 * j + 3]) for j in range(len(got))] == \
            [db.star_vector(i) for i in got]
    assert cell_span(1.0, 0.0, 0.01, 8) == (3, 5)     # the centre rows of a face
    assert cell_span(-0.5, 0.0, 0.01, 8) == (0, 8)    # behind the face: every row
    assert cell_span(0.6, 0.8, 0.01, 8) == (0, 0)     # beyond the face's edge


def test_block_reads_equal_star_by_star(tmp_path):
    """``star_vectors`` gives ``star_vector``'s values, from a buffer and from a file, at the
    end of the table, a whole block or fewer."""
    mem, f = _both_readers(estcube2_image(), tmp_path)
    try:
        n = mem.n_stars
        for db in (mem, f):
            for start in (0, 5, n - STAR_BLOCK, n - 3, n - 1):
                block = db.star_vectors(start)
                assert len(block) == 3 * min(STAR_BLOCK, n - start)
                for k in range(len(block) // 3):
                    assert tuple(block[3 * k:3 * k + 3]) == mem.star_vector(start + k)
                for size in (1, 7):             # a cell's stars: fewer than a block
                    assert db.star_vectors(start, size) == \
                        block[:3 * min(size, n - start)]
            assert db.cell_range(3) == (mem._cell_start(3), mem._cell_start(4))
    finally:
        f.close()


# --------------------------------------------------------------------------------------
# The SPI F-RAM source
# --------------------------------------------------------------------------------------

def _fram(image, base=0):
    """The F-RAM model (:class:`lodestar.regress.fram.Fram`) holding ``image`` at ``base``,
    the rest erased (``0xFF``)."""
    store = bytearray(b"\xff" * fram.CAPACITY)
    store[base:base + len(image)] = image
    return fram.Fram(io.BytesIO(bytes(store)))


@pytest.mark.parametrize("base", [0, 1, 65537, fram.CAPACITY - 40000])
def test_fram_reader_equals_buffer_reader(base):
    """``Database.fram`` over the chip's bus reads every record, cone and pair range as the
    buffer reader, at any base address (one ``READ`` per read, 4 command bytes each); the
    size defaults to the header's."""
    image = tiny_image() if base else estcube2_image()
    mem = Database(image)
    chip = _fram(image, base)
    db = Database.fram(chip, chip.cs, base=base)
    assert db.info() == mem.info() and chip.errors == 0 and chip.cs.value() == 1
    opened = chip.reads
    assert opened >= len(image) // 512       # the header, the directory, the CRC in chunks
    assert all_records(db) == all_records(mem)
    assert db.stars_in_cone((0.0, 0.6, 0.8), 0.3) == mem.stars_in_cone((0.0, 0.6, 0.8), 0.3)
    assert db.pairs_in_range(0.1, 0.12) == mem.pairs_in_range(0.1, 0.12)
    assert chip.reads > opened and chip.errors == 0


def test_fram_reader_refuses_what_the_buffer_reader_refuses():
    """A corrupted byte in F-RAM is the buffer reader's status; an image longer than what
    lies past ``base``, a base outside the chip and a bus error are ``DATABASE_IO`` (as
    statuses through ``DatabaseError``, never another exception)."""
    image = tiny_image()
    bad = bytearray(image)
    bad[len(image) // 2] ^= 0x10
    chip = _fram(bytes(bad))
    with pytest.raises(DatabaseError) as exc:
        Database.fram(chip, chip.cs)
    assert exc.value.status == status_of(bytes(bad)) == S.DATABASE_CORRUPT
    chip = _fram(image, fram.CAPACITY - len(image) + 1)
    with pytest.raises(DatabaseError) as exc:
        Database.fram(chip, chip.cs, base=fram.CAPACITY - len(image) + 1)
    assert exc.value.status in (S.DATABASE_IO, S.DATABASE_BAD_LENGTH)
    with pytest.raises(DatabaseError) as exc:
        Database.fram(chip, chip.cs, base=fram.CAPACITY)
    assert exc.value.status == S.DATABASE_IO

    class Broken(fram.Fram):
        def readinto(self, buf, write=0):
            raise OSError(5)

    chip = Broken(io.BytesIO(image))
    with pytest.raises(DatabaseError) as exc:
        Database.fram(chip, chip.cs)
    assert exc.value.status == S.DATABASE_IO and "F-RAM read at 0" in exc.value.reason
    assert chip.cs.value() == 1                       # CS released after the failure


# --------------------------------------------------------------------------------------
# Corruption and mismatch
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("flip", [0x01, 0x80, 0xFF])
def test_every_corrupted_byte_is_refused(flip):
    image = tiny_image()
    assert check(image) == (S.OK, "")
    for i in range(len(image)):
        b = bytearray(image)
        b[i] ^= flip
        status, reason = check(b)
        assert status != S.OK and reason, i
        if i >= stardb.HEADER_SIZE:
            assert status == S.DATABASE_CORRUPT


def test_corrupted_bytes_in_the_flight_image_are_refused():
    image = estcube2_image()
    rng = np.random.default_rng(11)
    positions = list(range(stardb.HEADER_SIZE)) + rng.integers(0, len(image), 300).tolist()
    for i in positions:
        b = bytearray(image)
        b[i] ^= int(rng.integers(1, 256))
        assert check(b)[0] != S.OK, i


def test_length_errors():
    image = tiny_image()
    assert status_of(image[:-1]) == S.DATABASE_BAD_LENGTH
    assert status_of(image + b"\0") == S.DATABASE_BAD_LENGTH
    assert status_of(image[:100]) == S.DATABASE_BAD_LENGTH
    assert status_of(b"") == S.DATABASE_BAD_LENGTH


def test_named_mismatches():
    image = tiny_image()
    assert status_of(b"XXXX" + image[4:]) == S.DATABASE_BAD_MAGIC
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, 4, 2))) == \
        S.DATABASE_BAD_VERSION
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, 6, 128))) == \
        S.DATABASE_BAD_VERSION
    # the triangle bit without its section (this reader serves every method bit)
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, 16, 2))) == \
        S.DATABASE_BAD_LAYOUT
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, 16, 8))) == \
        S.DATABASE_BAD_LAYOUT
    n_pairs = struct.unpack_from("<I", image, 48)[0]
    assert status_of(reseal(image, lambda b: struct.pack_into("<I", b, 48, n_pairs + 1))) == \
        S.DATABASE_BAD_LAYOUT
    # a section pointing outside the image, and two overlapping sections
    off = stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_KVECTOR
    assert status_of(reseal(image, lambda b: struct.pack_into("<I", b, off, len(image)))) == \
        S.DATABASE_BAD_LAYOUT
    stars_off = struct.unpack_from("<I", image, stardb.DIRECTORY_OFFSET)[0]
    cells_entry = stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_CELLS
    assert status_of(reseal(image, lambda b: struct.pack_into(
        "<I", b, cells_entry, stars_off))) == S.DATABASE_BAD_LAYOUT
    # a missing required section
    assert status_of(reseal(image, lambda b: struct.pack_into(
        "<II", b, stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_PAIRS, 0, 0))) == S.DATABASE_BAD_LAYOUT
    # more stars than a 16-bit index names (the contract's MAX_STARS)
    assert status_of(reseal(image, lambda b: struct.pack_into(
        "<I", b, 40, stardb.MAX_STARS + 1))) == S.DATABASE_BAD_LAYOUT      # n_stars
    # a NaN field of view
    assert status_of(reseal(image, lambda b: struct.pack_into("<f", b, 20, float("nan")))) == \
        S.DATABASE_BAD_LAYOUT


def test_fov_mismatch():
    image = tiny_image()
    fov_h = math.radians(20.0)
    Database(image, expected_fov_h=fov_h)
    assert status_of(image, expected_fov_h=fov_h * 1.1) == S.DATABASE_MISMATCH


def test_load_never_raises(tmp_path):
    image = tiny_image()
    db, status, reason = load(image)
    assert status == S.OK and db.n_stars > 0
    assert load(image[:-3])[:2] == (None, S.DATABASE_BAD_LENGTH)
    assert load(str(tmp_path / "missing.bin"))[:2] == (None, S.DATABASE_IO)
    bad = tmp_path / "bad.bin"
    bad.write_bytes(image[:-8] + b"\0" * 8)
    assert load(str(bad))[:2] == (None, S.DATABASE_CORRUPT)
    good = tmp_path / "good.bin"
    good.write_bytes(image)
    db, status, _ = load(str(good))
    assert status == S.OK
    db.close()




def test_out_of_heap_while_opening_is_a_status(tmp_path, monkeypatch):
    """``Database.open`` (and ``load``) report a ``MemoryError`` of the reader as
    ``OUT_OF_MEMORY`` and close the file; it escaped as an exception before."""
    path = tmp_path / "db.bin"
    path.write_bytes(tiny_image())

    def no_heap(self):
        raise MemoryError

    monkeypatch.setattr(Database, "_cell_centres", no_heap)
    with pytest.raises(DatabaseError) as info:
        Database.open(str(path))
    assert info.value.status == S.OUT_OF_MEMORY
    assert load(str(path))[:2] == (None, S.OUT_OF_MEMORY)
    assert check(tiny_image())[0] == S.OUT_OF_MEMORY
