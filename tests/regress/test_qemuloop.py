"""The flight executive and its link master on the Cortex-M4F build (issue 30's done-when):
the loop of :mod:`lodestar.regress.qemuloop` inside the session's image, each packet read by
the firmware's ``Link`` from :mod:`lodestar.regress.linkmodel` and solved through
``Executive.step``.  Its cost and heap: ``benchmarks/bench_executive.py``."""

import pytest

from lodestar.firmware import link
from lodestar.regress import qemu

pytestmark = pytest.mark.xdist_group("cortex_m4f")

CASES = ("estcube2_rest_s1", "estcube2_tracking_steady", "estcube2_tracking_budget",
         "frame_truncated", "corrupt_bit_flip")


def test_the_executive_runs_on_the_flight_build(cortex_m4f, regression_set):
    """A lost-in-space frame, two tracking frames, a frame the gateware cut short and a
    packet with a flipped bit: every packet the link accepts gives its recorded status and
    stars through the executive in the flight heap, the corrupt one is refused by the
    link's CRC-32 before the decoder sees it, and the loop goes on."""
    manifest, db_files = regression_set
    runs = [(case, "pyramid") for case in manifest["cases"] if case["name"] in CASES]
    assert len(runs) == len(CASES)
    loop = qemu.flight_loop(cortex_m4f, manifest, db_files, runs, heap=qemu.EXPECTATION_HEAP,
                            ballast=qemu.EXPECTATION_HEAP - qemu.FLIGHT_HEAP, executive=True)
    assert loop["finished"], loop["error"]
    for case, method in runs:
        out = loop["results"][case["name"], method][0]
        code = loop["link"][case["name"], method]
        if case["name"] == "corrupt_bit_flip":
            assert out is None and code == link.CODE_NAMES[link.PACKET_CRC]
            continue
        want = case["expected"][method]
        assert code == "OK" and (out["status"], out["matches"]) == \
            (want["status"], want["matches"]), case["name"]


DECODER_CHECKED = ("PACKET_BAD_HEADER", "PACKET_BAD_RECORD")
"""The packet statuses the decoder gives through the link too; the link checks the framing of
the others first (it refuses such a packet, or reads the packet its header delimits and
leaves a trailing byte to the next resynchronisation), as ``benchmarks/bench_mcu.py`` leaves
them out."""


def test_the_executive_loop_fits_its_flight_heap(cortex_m4f, regression_set):
    """Every estcube2 Pyramid packet of the set through the executive and its link in the
    flight heap (``qemu.FLIGHT_HEAP``, a ballast in the session's image): the recorded status
    and stars for every packet the link accepts, none out of heap."""
    manifest, db_files = regression_set
    runs = [(case, "pyramid") for case in manifest["cases"] if case["camera"] == "estcube2"]
    loop = qemu.flight_loop(cortex_m4f, manifest, db_files, runs, heap=qemu.EXPECTATION_HEAP,
                            ballast=qemu.EXPECTATION_HEAP - qemu.FLIGHT_HEAP, executive=True)
    assert loop["finished"], loop["error"]
    wrong = []
    for case, method in runs:
        out = loop["results"][case["name"], method][0]
        want = case["expected"][method]
        name = want["status_name"]
        if name.startswith("PACKET_") and name not in DECODER_CHECKED:
            continue                      # the link's own checks, before the decoder's
        if out is None or (out["status"], out["matches"]) != (want["status"], want["matches"]):
            wrong.append((case["name"], out and out["status_name"]))
    assert wrong == []
