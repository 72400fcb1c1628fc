"""The star-database layout of the contract against its specification, docs/stardb.md."""

import importlib
import re
import struct

from lodestar.contract import stardb as L
from tests import REPO

SPEC = REPO / "docs" / "stardb.md"


def test_formats_have_their_documented_sizes():
    assert struct.calcsize(L.HEADER_FORMAT) == L.DIRECTORY_OFFSET
    assert L.DIRECTORY_OFFSET + 8 * L.N_SECTIONS == L.RESERVED_OFFSET
    assert L.RESERVED_OFFSET + 4 == L.HEADER_CRC_OFFSET and L.HEADER_CRC_OFFSET + 4 == L.HEADER_SIZE
    assert struct.calcsize(L.STAR_FORMAT) == L.STAR_SIZE
    assert struct.calcsize(L.PAIR_FORMAT) == L.PAIR_SIZE
    assert struct.calcsize(L.TRI_HEADER_FORMAT) == L.TRI_HEADER_SIZE
    assert struct.calcsize(L.TRI_RECORD_FORMAT) == L.TRI_RECORD_SIZE
    assert struct.calcsize(L.HASH_HEADER_FORMAT) == L.HASH_HEADER_SIZE
    assert len(L.SECTION_NAMES) == L.N_SECTIONS


def test_methods_are_one_table_with_one_bit_each():
    assert tuple(L.METHOD_NAMES) == L.METHODS == tuple(m[0] for m in L.METHOD_TABLE)
    bits = [L.METHOD_NAMES[m] for m in L.METHODS]
    assert all(b & (b - 1) == 0 for b in bits) and len(set(bits)) == len(bits)
    assert bits == sorted(bits) and L.METHOD_MASK == sum(bits)
    assert set(L.METHOD_SECTIONS) == set(bits)
    for _, bit, module, sections, options in L.METHOD_TABLE:
        assert importlib.import_module(module).DATABASE_BIT == bit
        assert {L.SEC_STARS, L.SEC_CELLS} <= set(sections) < set(range(L.N_SECTIONS))
        assert all(isinstance(o, tuple) and len(o) == 2 for o in options)
        assert len({o[0] for o in options}) == len(options)


def test_keyed_sections_have_their_layout():
    for sec, prefix, magic, fmt, size, fields, key_format in L.KEYED_SECTIONS:
        assert 0 <= sec < L.N_SECTIONS
        assert struct.calcsize(fmt) == size and len(magic) == 4
        assert len(struct.unpack(fmt, bytes(size))) == len(fields)
        assert fields[:3] == ("magic", "n", "kv_bins") and "kv_m" in fields
        assert struct.calcsize(key_format) in (2, 4) and prefix.endswith("_")


def test_specification_names_the_layout_values():
    text = SPEC.read_text()
    assert re.search(r"\b{}\b".format(L.HEADER_SIZE), text)
    for name in ("payload_crc", "cells_per_face", "kv_bins"):
        assert name in text
