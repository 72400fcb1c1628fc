"""lodestar.firmware.status: one table row per code, names and meanings."""

from lodestar.firmware import status as S


def test_status_table():
    constants = {name: getattr(S, name) for name in dir(S)
                 if name.isupper() and isinstance(getattr(S, name), int)}
    rows = {row[1]: row for row in S._TABLE}
    assert set(constants) == set(rows)
    for name, code in constants.items():
        assert rows[name][0] == code
        assert S.name(code) == name
        assert S.meaning(code) == rows[name][2] and rows[name][2]
        assert "\n" not in rows[name][2]
    codes = [row[0] for row in S._TABLE]
    assert len(set(codes)) == len(codes) and codes == sorted(codes)
    assert S.codes() == tuple(codes)
    assert S.OK == 0
    assert S.name(999) == "UNKNOWN(999)" and S.meaning(999) == "unknown status"
    for name in ("PACKET_TRUNCATED", "PACKET_BAD_MAGIC", "PACKET_BAD_VERSION",
                 "PACKET_BAD_LENGTH", "PACKET_BAD_CRC", "PACKET_BAD_HEADER",
                 "PACKET_BAD_RECORD", "TOO_FEW_STARS", "NO_MATCH", "AMBIGUOUS",
                 "DATABASE_CORRUPT", "DATABASE_MISMATCH", "BAD_INPUT"):
        assert name in constants
