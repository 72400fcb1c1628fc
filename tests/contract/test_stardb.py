"""The star-database layout of the contract against its specification, docs/stardb.md."""

import importlib
import re
import struct

from lodestar.contract import stardb
from tests import REPO

SPEC = REPO / "docs" / "stardb.md"


def test_formats_have_their_documented_sizes():
    assert struct.calcsize(stardb.HEADER_FORMAT) == stardb.DIRECTORY_OFFSET
    assert stardb.DIRECTORY_OFFSET + 8 * stardb.N_SECTIONS == stardb.RESERVED_OFFSET
    assert stardb.RESERVED_OFFSET + 4 == stardb.HEADER_CRC_OFFSET
    assert stardb.HEADER_CRC_OFFSET + 4 == stardb.HEADER_SIZE
    assert struct.calcsize(stardb.STAR_FORMAT) == stardb.STAR_SIZE
    assert struct.calcsize(stardb.PAIR_FORMAT) == stardb.PAIR_SIZE
    assert struct.calcsize(stardb.TRI_HEADER_FORMAT) == stardb.TRI_HEADER_SIZE
    assert struct.calcsize(stardb.TRI_RECORD_FORMAT) == stardb.TRI_RECORD_SIZE
    assert struct.calcsize(stardb.HASH_HEADER_FORMAT) == stardb.HASH_HEADER_SIZE
    assert len(stardb.SECTION_NAMES) == stardb.N_SECTIONS


def test_methods_are_one_table_with_one_bit_each():
    assert tuple(stardb.METHOD_NAMES) == stardb.METHODS == tuple(m[0] for m in stardb.METHOD_TABLE)
    bits = [stardb.METHOD_NAMES[m] for m in stardb.METHODS]
    assert all(b & (b - 1) == 0 for b in bits) and len(set(bits)) == len(bits)
    assert bits == sorted(bits) and stardb.METHOD_MASK == sum(bits)
    assert set(stardb.METHOD_SECTIONS) == set(bits)
    for _, bit, module, sections, options in stardb.METHOD_TABLE:
        assert importlib.import_module(module).DATABASE_BIT == bit
        assert {stardb.SEC_STARS, stardb.SEC_CELLS} <= set(sections) < set(range(stardb.N_SECTIONS))
        assert all(isinstance(o, tuple) and len(o) == 2 for o in options)
        assert len({o[0] for o in options}) == len(options)


def test_keyed_sections_have_their_layout():
    for sec, prefix, magic, fmt, size, fields, key_format in stardb.KEYED_SECTIONS:
        assert 0 <= sec < stardb.N_SECTIONS
        assert struct.calcsize(fmt) == size and len(magic) == 4
        assert len(struct.unpack(fmt, bytes(size))) == len(fields)
        assert fields[:3] == ("magic", "n", "kv_bins") and "kv_m" in fields
        assert struct.calcsize(key_format) in (2, 4) and prefix.endswith("_")


def test_specification_names_the_layout_values():
    text = SPEC.read_text()
    assert re.search(r"\b{}\b".format(stardb.HEADER_SIZE), text)
    for name in ("payload_crc", "cells_per_face", "kv_bins"):
        assert name in text
