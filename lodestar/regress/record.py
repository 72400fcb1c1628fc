"""The recorder of the firmware regression set (``lodestar regress --record``): simulated
frames, golden detection, FPGA packets, derived packets, and their expected firmware outputs.

:data:`CASES` are simulated full frames (:func:`lodestar.sim.goldenset.render_spec`, seeded,
the attitude drawn uniformly from the seed as ``lodestar demo`` draws it) detected by the
golden model with the registers of :func:`lodestar.sim.scene.detector_config`; the packet is
:func:`lodestar.ground.codec.encode` of the detection.  :data:`DERIVED` packets are made from those
(corrupted, cut down, or replayed with the other camera).  Every packet is replayed on
CPython with each method of :data:`lodestar.regress.METHODS` through
:mod:`lodestar.regress.mcu` (the code MicroPython runs), and the outputs are checked
before anything is written:

* every solution is right against the simulator's truth (:mod:`lodestar.ground.truth`:
  attitude error below ``WRONG_ARCSEC``, every match inside the true star's grown bounding
  box); a derived packet never solves;
* each case's ``expect`` holds (``"solve"``: every method solves; ``"fail"``: none does;
  ``"any"``: no condition; a status name: every method returns it);
* replayed on the flight MCU's build, the Cortex-M4F image under QEMU
  (:func:`lodestar.regress.qemu.expectation_build`, its outcomes recorded as each case's
  ``expected_float32``), every packet gives the double status and identified stars, the
  attitude and the 1-sigma figures within :data:`lodestar.regress.replay.FLOAT32_BOUND` of
  the double ones.  Recording needs the build: where it cannot be made,
  :class:`lodestar.regress.qemu.Unavailable` is raised before anything else is done.

A case that breaks them is a firmware finding to report, not an expected output: the
recorder lists every such problem and writes nothing.  The manifest layout is documented in
:mod:`lodestar.regress`; recording twice gives the same files (every input is seeded).
"""

import dataclasses
import json
import math
import tempfile
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.firmware.settings import Settings
from lodestar.firmware.tracking import propagate
from lodestar.golden import detect_frame
from lodestar.ground import codec, onboard
from lodestar.ground import truth as _truth
from lodestar.ground.files import write_atomic
from lodestar.regress import mcu, qemu, replay
from lodestar.sim import attitude, goldenset, presets
from lodestar.sim.goldenset import DENSE, ORION


@dataclasses.dataclass(frozen=True)
class FrameCase:
    """A simulated frame: ``preset`` camera; attitude ``pointing`` (RA, Dec, roll in deg) or,
    when None, drawn uniformly from ``seed``, which also seeds the noise; body ``rate``
    (deg/s, camera frame); ``exposure_s`` (None: the preset's); sensor defects
    (``hot_pixels``), ``false_stars``, ``cosmic_rays``; ``gyro``: the firmware gets the
    rate; ``prior_error_deg``: tracking from the true attitude turned by this angle about the
    camera x axis (None: lost in space); ``budgeted``: detected as a flight loop in steady
    tracking sees the frame, with the ``min_sum`` register the firmware returns
    (``Result.min_sum``, Pyramid) for the same frame detected with every blob; ``expect``
    as in the manifest."""

    name: str
    preset: str
    seed: int
    rate: tuple = (0.0, 0.0, 0.0)
    exposure_s: float = None
    hot_pixels: bool = False
    false_stars: int = 0
    cosmic_rays: int = 0
    gyro: bool = True
    prior_error_deg: float = None
    budgeted: bool = False
    expect: str = "solve"
    note: str = ""
    pointing: tuple = None


@dataclasses.dataclass(frozen=True)
class DerivedCase:
    """A packet made from the packet of frame case ``base`` by ``kind`` (:data:`KINDS`),
    replayed with camera ``camera`` (None: the base's); ``expect`` as in the manifest."""

    name: str
    base: str
    kind: str
    expect: str
    camera: str = None
    note: str = ""


CASES = (
    FrameCase("estcube2_rest_s0", "estcube2", 0, note="the demo's default frame"),
    FrameCase("estcube2_rest_s1", "estcube2", 1),
    FrameCase("estcube2_rest_s2", "estcube2", 2),
    FrameCase("estcube2_rest_s3", "estcube2", 3),
    FrameCase("estcube2_rest_s4", "estcube2", 4),
    FrameCase("estcube2_rest_s5", "estcube2", 5),
    FrameCase("estcube2_0.5dps", "estcube2", 6, (0.4, 0.3, 0.0)),
    FrameCase("estcube2_1dps", "estcube2", 7, (0.6, -0.8, 0.0)),
    FrameCase("estcube2_2dps", "estcube2", 17, (1.2, -1.6, 0.0)),
    FrameCase("estcube2_3dps", "estcube2", 9, (2.4, 1.8, 0.0), expect="any"),
    FrameCase("estcube2_1dps_no_gyro", "estcube2", 10, (0.8, 0.6, 0.0), gyro=False,
              expect="any", note="turning, the firmware not told"),
    FrameCase("estcube2_tracking_1dps", "estcube2", 11, (0.0, 1.0, 0.0),
              prior_error_deg=0.1, note="tracking from a prior 0.1 deg off"),
    FrameCase("estcube2_tracking_steady", "estcube2", 18, (0.0, 1.0, 0.0),
              prior_error_deg=0.002, expect="IMPRECISE", note="steady tracking: a prior 7 "
              "arcsec off, as the last attitude propagated by the gyro over 0.1 s; 6 stars "
              "matched, whose residuals' Student-t tail puts the 5-sigma bound beyond 180 "
              "arcsec"),
    FrameCase("estcube2_tracking_budget", "estcube2", 0, prior_error_deg=0.002, budgeted=True,
              note="steady tracking at rest with the record budget: the demo's frame, 50 "
              "blobs, detected with the min_sum its own replay returns"),
    FrameCase("estcube2_tracking_budget_1dps", "estcube2", 7, (0.6, -0.8, 0.0),
              prior_error_deg=0.002, budgeted=True,
              note="steady tracking with the record budget: estcube2_1dps's frame"),
    FrameCase("estcube2_false_hot_cosmic", "estcube2", 12, hot_pixels=True, false_stars=8,
              cosmic_rays=12, note="8 false stars, hot pixels, 12 cosmic rays"),
    FrameCase("estcube2_10dps", "estcube2", 13, (8.0, 6.0, 0.0), expect="fail",
              note="smeared beyond detection"),
    FrameCase("estcube2_1ms", "estcube2", 14, exposure_s=0.001, expect="fail",
              note="1 ms exposure: too few stars"),
    FrameCase("lohmann_orion", "lohmann", 21, exposure_s=0.1, pointing=ORION,
              expect="IMPRECISE", note="7 stars matched: the bound's Student-t tail"),
    FrameCase("lohmann_cygnus", "lohmann", 22, exposure_s=0.2, pointing=DENSE),
    FrameCase("lohmann_rest_s20", "lohmann", 20, exposure_s=0.2, expect="IMPRECISE",
              note="7 stars matched: the bound's Student-t tail"),
    FrameCase("lohmann_cygnus_1dps", "lohmann", 23, (0.7, 0.7, 0.0), exposure_s=0.2,
              pointing=DENSE, expect="any"),
)
"""The simulated frames of the set."""

KINDS = ("bit_flip", "truncated", "trailing_byte", "bad_magic", "empty", "bad_header",
         "bad_record", "two_records", "frame_truncated", "other_camera")
"""Derivations: one bit flipped in the middle of the records; the last 7 bytes cut; a zero
byte appended; the first byte inverted; no bytes; the frame width set to 0 under a valid
CRC; record 0 with ``n = 0`` under a valid CRC; only the first two records (a valid packet);
the gateware's ``FRAME_TRUNCATED`` flag set (a valid packet of a frame cut short); the
packet unchanged, replayed with another camera (``camera``)."""

DERIVED = (
    DerivedCase("corrupt_bit_flip", "estcube2_rest_s0", "bit_flip", "PACKET_BAD_CRC"),
    DerivedCase("corrupt_truncated", "estcube2_rest_s0", "truncated", "PACKET_TRUNCATED"),
    DerivedCase("corrupt_trailing_byte", "estcube2_rest_s0", "trailing_byte",
                "PACKET_BAD_LENGTH"),
    DerivedCase("corrupt_bad_magic", "estcube2_rest_s0", "bad_magic", "PACKET_BAD_MAGIC"),
    DerivedCase("corrupt_empty", "estcube2_rest_s0", "empty", "PACKET_TRUNCATED"),
    DerivedCase("corrupt_bad_header", "estcube2_rest_s0", "bad_header", "PACKET_BAD_HEADER"),
    DerivedCase("corrupt_bad_record", "estcube2_rest_s0", "bad_record", "PACKET_BAD_RECORD"),
    DerivedCase("two_records", "estcube2_rest_s1", "two_records", "TOO_FEW_STARS"),
    DerivedCase("frame_truncated", "estcube2_rest_s0", "frame_truncated", "FRAME_INCOMPLETE",
                note="the frame flagged cut short: no attitude from partial records"),
    DerivedCase("lohmann_packet_on_estcube2", "lohmann_orion", "other_camera",
                "BAD_INPUT", camera="estcube2", note="frame size differs from the camera's"),
)
"""Packets derived from the frames' packets."""


def _frame(case, budget=None):
    """``(DetectionResult, truth)`` of a frame case; ``budget``: for a ``budgeted`` case, the
    function of ``(packet, inputs)`` of the frame with every blob that gives the ``min_sum``
    register to detect it with."""
    pointing = case.pointing
    if pointing is None:
        q = attitude.random_attitude(np.random.default_rng(case.seed))
        pointing = tuple(float(a) for a in attitude.to_radec_roll(q))
    spec = goldenset.FrameSpec(case.name, case.preset, pointing, case.rate, None,
                               case.exposure_s, case.hot_pixels, case.cosmic_rays,
                               case.false_stars, case.seed)
    frame, truth, cfg = goldenset.render_spec(spec)
    det = detect_frame(frame, cfg)
    if case.budgeted:
        cfg = dataclasses.replace(cfg, min_sum=budget(codec.encode(det), _inputs(case, truth)))
        det = detect_frame(frame, cfg)
    return det, truth


def derive(kind, det):
    """The packet bytes of derivation ``kind`` (:data:`KINDS`) of a detection result."""

    if kind not in KINDS:
        raise ValueError(f"unknown derivation {kind!r}; known: {', '.join(KINDS)}")
    data = codec.encode(det)
    if kind == "bit_flip":
        corrupt = bytearray(data)
        corrupt[len(data) // 2] ^= 0x10
        return bytes(corrupt)
    if kind == "truncated":
        return data[:-7]
    if kind == "trailing_byte":
        return data + b"\x00"
    if kind == "bad_magic":
        return bytes([data[0] ^ 0xFF]) + data[1:]
    if kind == "empty":
        return b""
    if kind == "bad_header":
        return codec.encode(det.replace(width=0))
    if kind == "bad_record":
        blobs = list(det.blobs)
        first = type(blobs[0])(**dict(zip(C.RECORD_NAMES, blobs[0].as_tuple())))
        first.n = 0
        return codec.encode(det.replace(blobs=[first] + blobs[1:]))
    if kind == "frame_truncated":
        return codec.encode(det.replace(flags=det.flags | C.FRAME_TRUNCATED))
    if kind == "two_records":
        kept = det.blobs[:2]
        return codec.encode(det.replace(
            blobs=kept, n_blobs=det.n_filtered + det.dropped_records + len(kept)))
    return data                                   # other_camera: the packet unchanged


def _prior(q_true, error_deg):
    """The true attitude turned by ``error_deg`` about the camera x axis."""
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_rotvec([math.radians(error_deg), 0.0, 0.0])
    return [float(v) for v in (turn * Rotation.from_quat(q_true)).as_quat()]


def _camera_settings(preset):

    cam = presets.load_preset(preset)
    fw = onboard.firmware_camera(cam)
    return fw, {"camera": fw.as_dict(), "exposure_s": cam.exposure_s,
                "row_time_s": cam.row_time_s if cam.shutter == "rolling" else 0.0,
                "tolerance_px": onboard.default_tolerance_px(fw), "database": preset}


def check_truth(out, det, truth):
    """``(error, problem)``: the attitude error of a solution against the truth
    at the instant it holds for (``t_epoch_s``) (``{"cross", "roll"}``, arcsec;
    :mod:`lodestar.ground.truth`) and None, or the problem when the solution is wrong."""

    err = _truth.attitude_error_arcsec(out["q"], propagate(
        truth["quaternion_xyzw"], [math.radians(w) for w in truth["omega_deg_s"]],
        out.get("t_epoch_s") or 0.0))
    matches = [(i, det.blobs[i].sx / det.blobs[i].s0, det.blobs[i].sy / det.blobs[i].s0, hip)
               for i, hip in out["matches"]]
    wrong = [row for row in _truth.match_rows(matches, det.blobs, truth["sources"])
             if not row["right"]]
    problem = None
    if err["total"] > _truth.WRONG_ARCSEC or wrong:
        problem = (f"WRONG solution: attitude error {err['total']:.0f}\" (cross "
                   f"{err['cross']:.1f}\", roll {err['roll']:.1f}\"), {len(wrong)} of "
                   f"{len(matches)} matches wrong (HIP {[r['hip'] for r in wrong]})")
    return {"cross": err["cross"], "roll": err["roll"]}, problem


def check_expect(expect, outcomes):
    """None when the outcomes meet ``expect``, else the problem."""
    statuses = {m: o["status_name"] for m, o in outcomes.items()}
    solved = [m for m, s in statuses.items() if s == "OK"]
    if expect == "solve":
        good = len(solved) == len(statuses)
    elif expect == "fail":
        good = not solved
    elif expect == "any":
        good = True
    else:
        good = all(s == expect for s in statuses.values())
    return None if good else f"expected {expect!r}, the firmware gave {statuses}"


def _inputs(case, truth):
    """The firmware inputs of a frame case (``docs/regression.md``)."""
    return {"omega": [math.radians(w) for w in case.rate] if case.gyro else None,
            "exposure_s": truth["exposure_s"],
            "prior": (None if case.prior_error_deg is None else
                      _prior(truth["quaternion_xyzw"], case.prior_error_deg)),
            "dt": None}


def frame_entry(case, budget=None):
    """``(det, truth, packet, inputs, truth_doc)`` of a frame case (``budget``: as for
    :func:`_frame`)."""

    det, truth = _frame(case, budget)
    inputs = _inputs(case, truth)
    truth_doc = {"q": truth["quaternion_xyzw"], "ra_deg": truth["ra_deg"],
                 "dec_deg": truth["dec_deg"], "roll_deg": truth["roll_deg"],
                 "rate_deg_s": truth["omega_deg_s"]}
    return det, truth, codec.encode(det), inputs, truth_doc


def add_float32(manifest, files, db_files, cache_dir=None):
    """Replay every case of ``manifest`` (its packets ``files``, ``{path in the set: bytes}``;
    its databases ``db_files``) with each method on the Cortex-M4F build
    (:func:`lodestar.regress.qemu.expectation_build` into ``cache_dir``,
    :func:`lodestar.regress.qemu.float32_outcomes`), add each case's ``expected_float32``
    and return the problems: every outcome that differs from the double one (``expected``)
    beyond the manifest's ``float32.bound`` (:func:`lodestar.regress.replay.float32_vs_double`)."""
    with tempfile.TemporaryDirectory() as tmp:
        for path, data in files.items():
            (Path(tmp) / path).parent.mkdir(parents=True, exist_ok=True)
            (Path(tmp) / path).write_bytes(data)
        elf = qemu.expectation_build(manifest, tmp, db_files, cache_dir)
        outcomes = qemu.float32_outcomes(elf, manifest, db_files)
    bound = manifest["float32"]["bound"]
    problems = []
    for case in manifest["cases"]:
        case["expected_float32"] = {m: outcomes[case["name"], m] for m in manifest["methods"]}
        for method, out in case["expected_float32"].items():
            problems += [f"{case['name']} / {method}: float32 vs double: {d}"
                         for d in replay.float32_vs_double(out, case["expected"][method],
                                                            bound)]
    return problems


def record_float32(set_dir, cache_dir=None):
    """Record the float32 expectations of the set in ``set_dir`` again on the flight build
    (:func:`add_float32`; its packets and double expectations stay as they are): what a
    change of the flight build's arithmetic (compiler, libm, FPU) needs.  Rewrites
    ``manifest.json`` atomically and returns the manifest; raises as :func:`record`
    (nothing is written when an outcome breaks the bound)."""
    manifest = replay.load_set(set_dir)
    qemu.check_available()
    files = {case["packet"]: (Path(set_dir) / case["packet"]).read_bytes()
             for case in manifest["cases"]}
    problems = add_float32(manifest, files, replay.database_files(manifest, cache_dir),
                           cache_dir)
    if problems:
        raise replay.RegressionError("nothing written: the float32 outcomes break the set's "
                                     "bound:\n  " + "\n  ".join(problems))
    manifest["float32"]["build"] = qemu.BUILD_NAME
    write_atomic(Path(set_dir) / "manifest.json",
                 (json.dumps(manifest, indent=1) + "\n").encode())
    return manifest


def record(set_dir, cache_dir=None, log=None):
    """Make the set and write it into ``set_dir`` (``manifest.json`` and ``packets/``; other
    files there are left alone).  ``cache_dir``: the database cache and the Cortex-M4F build's
    folder (default :func:`lodestar.ground.cache.default_cache_dir`).  ``log``: a text stream
    for progress (None: silent).  Returns the manifest.  Raises
    :class:`lodestar.regress.qemu.Unavailable` when the Cortex-M4F build cannot be made here,
    ``MicroPythonError`` when it fails, and :class:`lodestar.regress.RegressionError` listing
    every wrong solution, broken ``expect`` and float32 outcome beyond the bound (nothing is
    written in any of these cases)."""
    qemu.check_available()
    presets_used = sorted({c.preset for c in CASES} | {d.camera for d in DERIVED if d.camera})
    cameras, databases = {}, {}
    for preset in presets_used:
        fw_cam, cameras[preset] = _camera_settings(preset)
        recipe = replay.database_recipe(fw_cam)
        image = replay.build_image(recipe)
        databases[preset] = {"recipe": recipe, "sha256": replay.sha256(image),
                             "bytes": len(image)}
        replay.cache_image(image, cache_dir)
    manifest = {"format": replay.SET_FORMAT, "generator": "lodestar regress --record",
                "tolerances": dict(replay.TOLERANCES),
                "float32": {"build": qemu.BUILD_NAME,
                            "tolerances": dict(replay.FLOAT32_TOLERANCES),
                            "bound": dict(replay.FLOAT32_BOUND)},
                "methods": list(replay.METHODS),
                "databases": databases, "cameras": cameras, "cases": []}
    db_files = replay.database_files(manifest, cache_dir)
    trackers = {}
    for preset in presets_used:
        db = mcu.open_database(str(db_files[preset]))
        for method in replay.METHODS:
            trackers[preset, method] = mcu.make_tracker(db, cameras[preset], method)

    frames, files, problems = {}, {}, []
    for case in CASES + DERIVED:
        if isinstance(case, FrameCase):
            tracker = trackers[case.preset, Settings().method]     # the flight method
            det, truth, data, inputs, truth_doc = frame_entry(
                case, lambda data, inputs: mcu.process(tracker, data, inputs).min_sum)
            frames[case.name] = (det, truth, case)
            camera = case.preset
        else:
            det, truth, base = frames[case.base]
            data = derive(case.kind, det)
            camera = case.camera or base.preset
            inputs = {"omega": None, "exposure_s": truth["exposure_s"], "prior": None,
                      "dt": None}
            truth_doc = None
        outcomes = {m: mcu.replay(trackers[camera, m], data, inputs)
                    for m in replay.METHODS}
        errors = {}
        for method, out in outcomes.items():
            if out["status_name"] != "OK":
                continue
            if truth_doc is None:
                problems.append(f"{case.name} / {method}: a derived packet solved")
                continue
            error, problem = check_truth(out, det, truth)
            errors[method] = error
            if problem:
                problems.append(f"{case.name} / {method}: {problem}")
        problem = check_expect(case.expect, outcomes)
        if problem:
            problems.append(f"{case.name}: {problem}")
        path = f"packets/{case.name}.bin"
        files[path] = data
        manifest["cases"].append({
            "name": case.name, "camera": camera, "packet": path,
            "packet_sha256": replay.sha256(data), "note": case.note, "expect": case.expect,
            "inputs": inputs, "truth": truth_doc, "expected": outcomes,
            "expected_float32": {}, "error_arcsec": errors})      # float32: add_float32
        if log is not None:
            print(f"{case.name}: " + ", ".join(f"{m} {o['status_name']}"
                                               for m, o in outcomes.items()),
                  file=log, flush=True)
    if log is not None:
        print(f"float32 build {qemu.BUILD_NAME}: replaying every packet", file=log,
              flush=True)
    problems += add_float32(manifest, files, db_files, cache_dir)
    if problems:
        raise replay.RegressionError(
            "nothing written: the firmware's outputs break the set's rules (firmware "
            "findings to report, or cases to change):\n  " + "\n  ".join(problems))
    set_dir = Path(set_dir)
    (set_dir / "packets").mkdir(parents=True, exist_ok=True)
    for path, data in files.items():
        (set_dir / path).write_bytes(data)
    (set_dir / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest
