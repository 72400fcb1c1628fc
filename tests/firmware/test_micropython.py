"""The firmware under MicroPython 1.27 (WebAssembly port in Node): every ``firmware/*.py``
imports, and packet decoding, centroids and the camera model give the CPython results
(exact for ints, 1e-9 relative for floats).  Also reports the heap used by a decode.

The CPython side builds the cases (packets from the golden detector, corrupted packets, the
firmware's own CPython results) and embeds them as literals in one MicroPython script.
Requires ``node`` and ``npm ci --prefix tools/micropython`` (see ``tests/conftest.py``).
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from lodestar import contract as C
from lodestar import firmware
from lodestar.contract import DetectionResult, stardb
from lodestar.firmware import camera, centroids, packet
from lodestar.firmware import status as S
from lodestar.golden import Detector, DetectorConfig
from lodestar.golden.starfield import star_frame
from lodestar.ground import codec
from lodestar.regress import micropython as _micropython
from lodestar.sim.presets import PRESETS, load_preset
from tests.firmware.mpy import lit

FIRMWARE = Path(firmware.__file__).parent


# --------------------------------------------------------------------------------------
# Literals MicroPython can parse (repr of inf/nan is not a literal)
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# Cases computed on CPython
# --------------------------------------------------------------------------------------

def _frame_result(seed, n_stars, width, height, pixel_bits=12, record_capacity=512):
    frame, _ = star_frame(width=width, height=height, pixel_bits=pixel_bits, n_stars=n_stars,
                          seed=seed, sigma=1.5)
    cfg = DetectorConfig(width=width, height=height, pixel_bits=pixel_bits, threshold=80,
                         background=40, min_pixels=2, record_capacity=record_capacity)
    return Detector(cfg).process(frame)


def packet_cases():
    """``(name, bytes)`` of valid packets: star fields (one with exactly 100 records), a
    saturated blob, an empty frame."""
    big = _frame_result(1, 160, 640, 480, record_capacity=100)
    assert len(big.blobs) == 100 and big.dropped_records > 0
    saturated = Detector(DetectorConfig(width=40, height=30, pixel_bits=8, threshold=10)
                         ).process(np.full((30, 40), 255, dtype=np.uint16))
    empty = DetectionResult(blobs=[], mode=C.MODE_LOCAL, threshold=16, background=0,
                            n_blobs=0, n_filtered=0, dropped_records=0, dropped_labels=0,
                            flags=0, frame_counter=0xFFFFFFFF, width=C.MAX_WIDTH,
                            height=C.MAX_HEIGHT, pixel_bits=16)
    return [("stars100", codec.encode(big)),
            ("stars10bit", codec.encode(_frame_result(2, 30, 200, 150, pixel_bits=10))),
            ("stars16bit", codec.encode(_frame_result(3, 30, 200, 150, pixel_bits=16))),
            ("saturated", codec.encode(saturated)),
            ("empty", codec.encode(empty))]


def corrupt_cases(data):
    """Corrupted versions of a packet: bit flips spread over it, truncations, extra bytes,
    and semantically wrong fields with a correct CRC."""
    out = []
    for bit in range(0, 8 * len(data), 37):
        corrupt = bytearray(data)
        corrupt[bit // 8] ^= 0x80 >> (bit % 8)
        out.append(bytes(corrupt))
    for length in (0, 1, C.packet_bytes(0) - 1, C.packet_bytes(0), len(data) - 1):
        out.append(data[:length])
    out.append(data + b"\x00")
    word = int.from_bytes(data[:-C.CRC_BYTES], "big")
    body_bits = 8 * (len(data) - C.CRC_BYTES)
    width_at = next(at for name, at, _ in C.field_offsets(C.HEADER_FIELDS) if name == "width")
    for offset, bits, value in ((width_at, 16, 0),                        # header: width 0
                                (8 * C.HEADER_BYTES, 25, 0)):             # record 0: n 0
        shift = body_bits - offset - bits
        patched = (word & ~(((1 << bits) - 1) << shift)) | (value << shift)
        body = patched.to_bytes(len(data) - C.CRC_BYTES, "big")
        out.append(body + C.crc32(body).to_bytes(C.CRC_BYTES, "big"))
    return out


def star_tuple(star):
    return star.as_tuple()


def camera_cases():
    """Per preset: constructor dict, pixels and their CPython vectors, vectors and their
    pixels, and smears."""
    cases = []
    rng = np.random.default_rng(11)
    for name in PRESETS:
        sim = load_preset(name)
        cam = camera.Camera(sim.width, sim.height, sim.fx_px, sim.fy_px, sim.cx, sim.cy,
                              sim.k1, sim.k2, sim.k3, sim.p1, sim.p2)
        w, h = sim.width, sim.height
        pixels = [(x, y) for x in (-0.5, 0.0, w / 3, w / 2 - 0.5, w - 1.0, w - 0.5)
                  for y in (-0.5, 0.0, h / 3, h - 1.0, h - 0.5)]
        pixels += [(float(x), float(y)) for x, y in rng.uniform((-0.5, -0.5), (w - 0.5, h - 0.5),
                                                                (20, 2))]
        vectors = [cam.pixel_to_vector(x, y) for x, y in pixels]
        directions = [tuple(float(c) for c in v) for v in rng.normal(0, 0.1, (20, 3)) + (0, 0, 1)]
        projected = [cam.vector_to_pixel(v) for v in directions]
        omega = (0.01, -0.02, 0.03)
        smears = [cam.smear_px(x, y, omega, 0.1) for x, y in pixels[:10]]
        cases.append((cam.as_dict(), pixels, vectors, directions, projected, omega, smears))
    return cases


def build_script():
    """The MicroPython script with every case and expected result embedded."""
    packets = packet_cases()
    decoded = []
    for name, data in packets:
        code, header, records, reason = packet.decode(data)
        assert code == S.OK, reason
        stars, rejected = centroids.extract(records, max_stars=None)
        stars_smear, rejected_smear = centroids.extract(
            records, max_stars=20, expected_smear_px=(6.0, -4.0), max_elongation=1.5)
        decoded.append((name, data, header, [r.as_tuple() for r in records],
                        [star_tuple(s) for s in stars], rejected,
                        [star_tuple(s) for s in stars_smear], rejected_smear))
    corrupt = []
    for data in corrupt_cases(packets[1][1]):
        code, header, records, reason = packet.decode(data)
        assert code != S.OK
        corrupt.append((data, code, reason))
    firmware_modules = sorted(p.stem for p in (FIRMWARE).glob("*.py")
                              if p.name != "__init__.py")
    data_block = "\n".join([
        "MODULES_EXPECTED = " + lit(firmware_modules),
        "DECODED = " + lit(decoded),
        "CORRUPT = " + lit(corrupt),
        "CAMERAS = " + lit(camera_cases()),
        "STATUS_NAMES = " + lit([(code, S.name(code)) for code in S.codes()]),
        "BAD_INPUTS = " + lit([(bad, packet.decode(bad)) for bad in ("LS", 5, None, [1, 2])]),
    ])
    return data_block + "\n" + MICROPYTHON_SCRIPT


MICROPYTHON_SCRIPT = r'''
import gc
import os
import sys

print("IMPLEMENTATION", sys.implementation.name, sys.implementation.version)

# --- every firmware module imports -----------------------------------------------------
names = sorted(n[:-3] for n in os.listdir("/lib/lodestar/firmware")
               if n.endswith(".py") and n != "__init__.py")
print("MODULES", " ".join(names))
assert names == MODULES_EXPECTED, (names, MODULES_EXPECTED)
import lodestar.contract
for n in names:
    __import__("lodestar.firmware." + n)

from lodestar import contract as C
from lodestar.firmware import camera, centroids, packet, status

checks = [0]


def same(a, b, where):
    """ints (and bools, strings, bytes, None) exactly; floats to 1e-9 relative."""
    checks[0] += 1
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        if len(a) != len(b):
            raise AssertionError("{}: length {} != {}".format(where, len(a), len(b)))
        for i in range(len(a)):
            same(a[i], b[i], "{}[{}]".format(where, i))
        return
    if isinstance(a, dict) and isinstance(b, dict):
        if sorted(a) != sorted(b):
            raise AssertionError("{}: keys {} != {}".format(where, sorted(a), sorted(b)))
        for k in a:
            same(a[k], b[k], "{}[{}]".format(where, k))
        return
    if isinstance(a, float) or isinstance(b, float):
        if not (isinstance(a, float) and isinstance(b, float)):
            raise AssertionError("{}: types {!r} {!r}".format(where, a, b))
        if a == b or (a != a and b != b):
            return
        if abs(a - b) <= 1e-9 * max(abs(a), abs(b)) or abs(a - b) <= 1e-12:
            return
        raise AssertionError("{}: {!r} != {!r}".format(where, a, b))
    if type(a) is not type(b) or a != b:
        raise AssertionError("{}: {!r} != {!r}".format(where, a, b))


for code, name in STATUS_NAMES:
    same(status.name(code), name, "status")

# --- packets -----------------------------------------------------------------------------
import binascii
print("BINASCII_CRC32", hasattr(binascii, "crc32"), C.crc32_native is not None)
for crc_impl in ("binascii", "table"):
    if crc_impl == "table":
        C.crc32_native = None
    for name, data, header, records, stars, rejected, stars_s, rejected_s in DECODED:
        where = "{} ({})".format(name, crc_impl)
        code, h, recs, reason = packet.decode(data)
        same((code, reason), (status.OK, ""), where + " status")
        same(h, header, where + " header")
        same([r.as_tuple() for r in recs], records, where + " records")
        for r in recs:
            assert isinstance(r, C.BlobRecord)
        same(packet.decode(bytearray(data))[2] == recs, True, where + " bytearray")
        same(packet.decode(memoryview(data))[2] == recs, True, where + " memoryview")
        got, rej = centroids.extract(recs, max_stars=None)
        same([s.as_tuple() for s in got], stars, where + " stars")
        same(rej, rejected, where + " rejected")
        got, rej = centroids.extract(recs, max_stars=20, expected_smear_px=(6.0, -4.0),
                                     max_elongation=1.5)
        same([s.as_tuple() for s in got], stars_s, where + " stars (smear)")
        same(rej, rejected_s, where + " rejected (smear)")
    for data, code, reason in CORRUPT:
        out = packet.decode(data)
        same(out, (code, None, [], reason), "corrupt ({})".format(crc_impl))
    for bad, expected in BAD_INPUTS:
        same(packet.decode(bad), expected, "bad input")
    same(C.crc32(b"123456789"), 0xCBF43926, "crc check value")
C.crc32_native = binascii.crc32 if hasattr(binascii, "crc32") else None
same(C.crc32_table(b"123456789"), 0xCBF43926, "table crc check value")

# --- camera ------------------------------------------------------------------------------
for params, pixels, vectors, directions, projected, omega, smears in CAMERAS:
    cam = camera.Camera.from_dict(params)
    for (x, y), v in zip(pixels, vectors):
        same(cam.pixel_to_vector(x, y), v, "pixel_to_vector({}, {})".format(x, y))
    for v, p in zip(directions, projected):
        same(cam.vector_to_pixel(v), p, "vector_to_pixel")
    for (x, y), s in zip(pixels, smears):
        same(cam.smear_px(x, y, omega, 0.1), s, "smear_px")
    same(cam.pixel_to_vector(float("nan"), 0.0), None, "nan pixel")

# --- heap used by decoding the 100-record packet -----------------------------------------
# gc.collect() frees only what earlier runPython calls allocated (see run.mjs), so each
# measurement starts in a new part; allocation is counted with the collector disabled, an
# upper bound of the peak (nothing is freed during the call).
BIG = DECODED[0][1]
assert DECODED[0][0] == "stars100" and len(DECODED[0][3]) == 100
MEM = {}
#@split
gc.collect()
MEM["base"] = gc.mem_alloc()
gc.disable()
RESULT = packet.decode(BIG)
MEM["decode_allocated"] = gc.mem_alloc() - MEM["base"]
gc.enable()
assert RESULT[0] == status.OK
#@split
gc.collect()
MEM["decode_retained"] = gc.mem_alloc() - MEM["base"]
MEM["base"] = gc.mem_alloc()
gc.disable()
STARS = centroids.extract(RESULT[2], max_stars=None)
MEM["centroids_allocated"] = gc.mem_alloc() - MEM["base"]
gc.enable()
#@split
gc.collect()
MEM["centroids_retained"] = gc.mem_alloc() - MEM["base"]
print("MEM decode100 packet_bytes={} allocated={} retained={}".format(
    len(BIG), MEM["decode_allocated"], MEM["decode_retained"]))
print("MEM centroids100 stars={} allocated={} retained={}".format(
    len(STARS[0]), MEM["centroids_allocated"], MEM["centroids_retained"]))
print("CHECKS", checks[0])
print("DONE")
'''


def test_firmware_under_micropython(micropython):
    script = build_script()
    code, out = micropython(script)
    print(out)
    assert code == 0, out
    assert "DONE" in out
    assert re.search(r"IMPLEMENTATION micropython \(1, 27", out), out
    modules = re.search(r"^MODULES (.*)$", out, re.M).group(1).split()
    assert {"status", "packet", "centroids", "camera"} <= set(modules)
    assert int(re.search(r"^CHECKS (\d+)$", out, re.M).group(1)) > 1000
    mem = re.search(r"^MEM decode100 packet_bytes=(\d+) allocated=(\d+) retained=(\d+)$",
                    out, re.M)
    assert int(mem.group(1)) == C.packet_bytes(100)
    # decoding 100 records must fit comfortably in the MCU's 192 KB of RAM
    allocated, retained = int(mem.group(2)), int(mem.group(3))
    assert 0 < retained <= allocated < 96 * 1024, out


def test_runner_reports_errors(micropython):
    code, out = micropython("print('before')\nraise ValueError('boom')\n")
    assert code == 1
    assert "before" in out and "ValueError: boom" in out
    code, out = micropython("import lodestar.firmware.no_such_module\n")
    assert code == 1 and "ImportError" in out
    code, out = micropython("print('no newline', end='')")
    assert code == 0 and "no newline" in out


def test_literals_round_trip():
    value = [1, -2, 1 << 70, 0.1, float("inf"), -float("inf"), b"\x00\xff", "a'b", None,
             (1,), (), {"k": (2.5, True)}]
    assert eval(lit(value)) == value
    assert math.isnan(eval(lit(float("nan"))))
    with pytest.raises(TypeError):
        lit(object())


def test_missing_micropython_skips_or_fails(micropython, monkeypatch, tmp_path):
    """Without the npm package the tests skip with the install command, unless CI demands
    MicroPython (``LODESTAR_REQUIRE_MICROPYTHON``)."""
    monkeypatch.setenv("LODESTAR_MICROPYTHON_TOOL", str(tmp_path / "missing"))
    monkeypatch.setattr("shutil.which", lambda name: "/usr/bin/" + name)
    monkeypatch.delenv("LODESTAR_REQUIRE_MICROPYTHON", raising=False)
    with pytest.raises(pytest.skip.Exception, match="npm ci --prefix tools/micropython"):
        micropython("print(1)")
    monkeypatch.setenv("LODESTAR_REQUIRE_MICROPYTHON", "1")
    with pytest.raises(pytest.fail.Exception, match="MicroPython required"):
        micropython("print(1)")
    monkeypatch.setattr("shutil.which", lambda name: None)   # no node
    assert "node is not installed" in _micropython.unavailable_reason()


@pytest.mark.parametrize("name", ["status", "packet", "centroids", "camera"])
def test_no_layout_number_is_restated(name):
    """The record/header widths come from the contract, never as numbers in the decoding
    modules (the import and f-string rules: ``tests/firmware/test_rules.py``)."""
    source = (FIRMWARE / (name + ".py")).read_text()
    for width in (C.RECORD_BYTES, C.HEADER_BYTES, C.RECORD_BITS, C.HEADER_BITS):
        if name == "status" and width in S.codes():
            continue                      # a status code that happens to equal a width
        assert not re.search(r"\b{}\b".format(width), source), (name, width)


def test_contract_names_and_import_threshold_under_micropython(micropython):
    """MicroPython resolves the contract package's names through its module ``__getattr__``
    (``MICROPY_MODULE_GETATTR``), keeps only those read, and importing the firmware sets
    the import-time collection threshold (``lodestar.firmware.IMPORT_GC_THRESHOLD``)."""
    code, out = micropython(
        "import gc\n"
        "from lodestar import contract as C\n"
        "n = len(C.__dict__)\n"
        "from lodestar.contract import REGISTER_BY_NAME, stardb\n"
        "import lodestar.firmware as F\n"
        "print('NAMES', n < 20, C.MAX_WIDTH, REGISTER_BY_NAME['mode'].address,\n"
        "      stardb.METHOD_PYRAMID, 'MAX_HEIGHT' in C.__dict__, 'link' in C.__dict__)\n"
        "print('THRESHOLD', gc.threshold() == F.IMPORT_GC_THRESHOLD)\n"
        "try:\n"
        "    C.NO_SUCH_NAME\n"
        "except AttributeError:\n"
        "    print('UNKNOWN AttributeError')\n")
    assert code == 0, out
    assert f"NAMES True 4096 0 {stardb.METHOD_PYRAMID} False False" in out, out
    assert "THRESHOLD True" in out and "UNKNOWN AttributeError" in out, out
