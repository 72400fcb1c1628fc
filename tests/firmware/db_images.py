"""Star-database images altered for the reader's tests: fields patched with both CRCs
recomputed (so only the layout is wrong), and the status the reader refuses one with."""

import re
import struct

import pytest

from lodestar.contract import packet, stardb
from lodestar.firmware import database
from lodestar.firmware import status as S
from lodestar.firmware.database import Database, DatabaseError


def _field_offset(name):
    """Byte offset of header field ``name`` from the contract's header format."""
    codes = re.findall(r"\d*[a-zA-Z]", stardb.HEADER_FORMAT[1:])
    index = stardb.HEADER_FIELDS.index(name)
    return struct.calcsize(stardb.HEADER_FORMAT[0] + "".join(codes[:index]))


PAYLOAD_CRC_OFFSET = _field_offset("payload_crc")


def reseal(image, patch=None):
    """``image`` with ``patch(bytearray)`` applied and both CRCs (payload, header)
    recomputed."""
    b = bytearray(image)
    if patch:
        patch(b)
    if len(b) >= stardb.HEADER_SIZE:
        struct.pack_into("<I", b, PAYLOAD_CRC_OFFSET,
                         packet.crc32(bytes(b[stardb.HEADER_SIZE:])))
        struct.pack_into("<I", b, stardb.HEADER_CRC_OFFSET,
                         packet.crc32(bytes(b[:stardb.HEADER_CRC_OFFSET])))
    return bytes(b)


def status_of(image, **kw):
    """The status :class:`Database` refuses ``image`` with (it must refuse it), checking the
    error names its status and a reason."""
    with pytest.raises(DatabaseError) as info:
        Database(image, **kw)
    assert info.value.status in database.STATUSES and info.value.reason
    assert str(info.value).startswith(S.name(info.value.status) + ": ")
    return info.value.status
