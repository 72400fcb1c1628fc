"""Property-based fuzzing of every input a user or the FPGA hands lodestar: packets,
centroid lists, image files, star databases and command lines.  Invariants: no traceback,
an exit code of the README's table, no wrong attitude, no user file changed, every flight
call within its work budget.

The default run keeps the examples few (``LODESTAR_FUZZ_EXAMPLES``, default 20 per
property); a longer campaign: ``LODESTAR_FUZZ_EXAMPLES=2000 pytest tests/fuzz``."""

import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lodestar import contract as C
from lodestar.cli import main
from lodestar.firmware import database
from lodestar.firmware import status as S
from lodestar.ground import imagesolve
from lodestar.ground.solve import solve_centroids
from lodestar.ground.truth import attitude_error_arcsec
from lodestar.regress import mcu, replay
from tests.firmware.db_images import reseal as reseal_database

FUZZ = settings(max_examples=int(os.environ.get("LODESTAR_FUZZ_EXAMPLES", "20")),
                deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                      HealthCheck.too_slow])
STATUSES = set(S.codes())
WRONG_ARCSEC = 120.0
"""An accepted attitude further than this from the unmodified packet's is wrong."""


@pytest.fixture(scope="module")
def flight():
    """``(tracker, packet, case)``: the regression set's demo frame and its tracker."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    case = next(c for c in manifest["cases"] if c["name"] == "estcube2_rest_s0")
    db_files = replay.database_files(manifest)
    camera = manifest["cameras"][case["camera"]]
    tracker = mcu.make_tracker(mcu.open_database(str(db_files[camera["database"]])), camera,
                               "pyramid")
    packet = replay.packets(manifest, replay.DEFAULT_SET)[case["name"]]
    return tracker, packet, case


def _reseal(data):
    """``data`` with its CRC trailer recomputed (so the semantic checks are reached)."""
    body = data[:-C.CRC_BYTES]
    return body + C.crc32(body).to_bytes(C.CRC_BYTES, "big")


def _check_result(result, case, spent):
    assert result.status in STATUSES
    if result.status == S.OK:
        err = attitude_error_arcsec(result.q, case["truth"]["q"])
        assert err["cross"] < WRONG_ARCSEC, (err, result)
    assert all(work <= limit or result.status == S.BUDGET_EXHAUSTED for work, limit in spent)


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1,
                      max_size=12), reseal=st.booleans(), cut=st.integers(0, 10 ** 6))
def test_mutated_packets(flight, work_spent, edits, reseal, cut):
    """Flipped bytes, resealed or not, and truncations: a status, never a wrong attitude."""
    tracker, packet, case = flight
    work_spent.clear()                  # the fixture outlives one example
    data = bytearray(packet)
    for pos, value in edits:
        data[pos % len(data)] = value
    if cut % 4 == 0:
        data = data[:cut % (len(data) + 1)]
    elif reseal and len(data) > C.CRC_BYTES:
        data = bytearray(_reseal(bytes(data)))
    result = tracker.process(bytes(data), exposure_s=0.1)
    _check_result(result, case, work_spent)


@FUZZ
@given(data=st.binary(max_size=4096))
def test_random_bytes_as_a_packet(flight, data):
    tracker, _packet, _case = flight
    assert tracker.process(data).status in STATUSES


_coordinate = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                        st.floats(-100, 3000), st.integers(-10, 3000))


@FUZZ
@given(centroids=st.lists(st.tuples(_coordinate, _coordinate, _coordinate), max_size=60),
       fov=st.one_of(st.floats(allow_nan=True), st.floats(0.5, 95.0)),
       width=st.integers(-5, 5000), height=st.integers(-5, 5000))
def test_centroid_lists(tmp_path_factory, work_spent, centroids, fov, width, height):
    """Any centroid list, frame size and FOV: a status (never an exception), and an attitude
    only with matches, within the work budget."""
    work_spent.clear()                  # the fixture outlives one example
    result = solve_centroids(centroids, width, height, fov,
                             cache_dir=tmp_path_factory.getbasetemp() / "fuzz-cache")
    assert result.status in STATUSES
    if result.status == S.OK:
        assert result.matches and all(math.isfinite(v) for v in result.q)
    assert all(work <= limit or result.status == S.BUDGET_EXHAUSTED
               for work, limit in work_spent)


_HEADS = [magic for magic, _format in imagesolve._MAGIC]
"""The first bytes by which ``lodestar solve`` recognises PNG, TIFF (also BigTIFF) and FITS."""


@FUZZ
@given(head=st.sampled_from(_HEADS), body=st.binary(max_size=3000),
       extra=st.sampled_from([[], ["--fov", "20"], ["--fov", "20", "--bin", "2"],
                              ["--bits", "12", "--fov", "15"]]))
def test_image_files(tmp_path_factory, capsys, head, body, extra):
    """Files that start like a PNG, TIFF or FITS and then hold anything: exit 0, 1 or 2 and
    the file is unchanged."""
    folder = tmp_path_factory.mktemp("img")
    path = folder / "sky.img"
    path.write_bytes(head + body)
    code = main(["solve", str(path), *extra])
    assert code in (0, 1, 2)
    assert path.read_bytes() == head + body
    assert "Traceback" not in capsys.readouterr().err


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1,
                      max_size=8), reseal=st.booleans(), cut=st.integers(0, 10 ** 6))
def test_corrupted_databases(database_image, edits, reseal, cut):
    """A corrupted database image (CRCs resealed or not, truncated): the reader returns a
    status, or a database every query of which stays safe."""
    data = bytearray(database_image)
    for pos, value in edits:
        data[pos % len(data)] = value
    if cut % 3 == 0:
        data = data[:cut % (len(data) + 1)]
    elif reseal:
        data = reseal_database(data)
    status, _reason = database.check(bytes(data))
    assert status in STATUSES


@pytest.fixture(scope="module")
def database_image():
    from lodestar.ground.database import build_database

    return build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=4.5,
                          methods=("pyramid", "triangle", "hashing"))


_VALUES = st.sampled_from(["0", "-1", "1e9", "nan", "inf", "x", "", "4096", "3.5", "-0",
                           "99999999999999999999"])


@FUZZ
@given(command=st.sampled_from([["detect", "--width", "{v}", "--height", "16"],
                                ["detect", "--width", "32", "--height", "16",
                                 "--stars", "{v}"],
                                ["detect", "--width", "32", "--height", "16",
                                 "--threshold", "{v}"],
                                ["detect", "--width", "32", "--height", "16",
                                 "--ksigma", "{v}", "--mode", "global"],
                                ["db", "build", "--fov", "{v}", "-o", "{out}"],
                                ["db", "build", "--fov", "20", "--aspect", "{v}", "--mag",
                                 "3", "-o", "{out}"],
                                ["db", "info", "{v}"],
                                ["simulate", "--exposure", "{v}", "-o", "{out}"]]),
       value=_VALUES)
def test_command_lines(tmp_path_factory, capsys, command, value):
    """Hostile values for the commands' options: exit 0, 1 or 2 (argparse's own exit 2
    included), one line of error, no traceback."""
    out = tmp_path_factory.mktemp("cli") / "out"
    argv = [a.format(v=value, out=out) for a in command]
    try:
        code = main(argv)
    except SystemExit as exc:                   # argparse refusing a value
        code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 1, 2), (argv, code, err)
    assert "Traceback" not in err
    if code == 2 and "usage:" not in err:
        assert len(err.strip().splitlines()) == 1, (argv, err)
