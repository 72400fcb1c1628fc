"""``lodestar.cosim``: stimulus, output parsing, ``run_frames`` and the ``lodestar cosim``
command (the broad gateware verification is ``cocotb_tests/test_detector.py``)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.cli import main
from lodestar.cosim import runner
from lodestar.golden import Detector, DetectorConfig

# the Verilated detector builds are shared (cached, one build per parameter set): one
# worker runs every test that plays them, so none waits on the other's build (pyproject:
# loadgroup)
pytestmark = pytest.mark.xdist_group("cosim")

GOLDEN = "tests/data/golden_small"


def test_stimulus_words():
    frame = np.array([[1, 2, 3], [4, 5, 6]], dtype=np.uint16)
    words = runner.Stimulus().reset(1).registers({"threshold": 9}) \
        .frame(frame, 1, 2).words(reader=lambda clock: clock != 3)
    valid = 1 << 18
    assert len(words) == 1 + 1 + 2 * 4 + 2
    assert words[0] & (1 << 21) and words[1] >> 32 == 9
    pixels = [int(w) & 0xFFFF for w in words if w & valid]
    assert pixels == [1, 2, 3, 4, 5, 6]
    assert int(words[2]) & (1 << 17) and int(words[4]) & (1 << 16)      # sof, eol
    assert not words[3] & (1 << 19) and words[2] & (1 << 19)            # reader
    cut = runner.Stimulus().frame(frame, 1, 0, pixels=4).words()
    assert [int(w) & 0xFFFF for w in cut if w & valid] == [1, 2, 3, 4]


def play_file(data):
    """The clock words ``harness.sv`` plays from a stimulus file (its command loop, in
    Python)."""
    out, at = [], 0
    while at < len(data):
        cmd = int.from_bytes(data[at:at + 8], "big")
        at += 8
        n = cmd >> 32
        if cmd & (1 << 23):
            assert 0 < n <= runner.RUN_MAX
            base = cmd & 0xFF_3C_00_00                     # control bits, no sof/eol/data
            for i in range(n):
                pixel = int.from_bytes(data[at + 2 * i:at + 2 * i + 2], "big")
                sof = cmd & (1 << 17) if i == 0 else 0
                eol = cmd & (1 << 16) if i == n - 1 else 0
                out.append(base | sof | eol | pixel)
            at += 2 * n
        elif cmd & (1 << 22):
            assert n > 0
            out += [cmd & 0xFF_3F_FF_FF] * n
        else:
            out.append(cmd)
    return out


def test_stimulus_file_plays_every_word():
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 4096, (5, 4100), dtype=np.uint16)      # rows beyond RUN_MAX
    stim = runner.Stimulus().reset(3).registers({"threshold": 9, "background": 0}) \
        .idle(5000).frame(frame, 1, 7).frame(frame[:, :3], 0, 1).frame(frame, 2, 0, pixels=9)
    for reader in (None, lambda clock: clock % 7 != 3):
        words = stim.words(reader)
        data = runner.encode(words)
        assert play_file(data) == [int(w) for w in words]
    assert len(runner.encode(stim.words())) < 2.1 * len(words)      # about 2 bytes a pixel
    assert runner.encode([]) == b""
    with pytest.raises(ValueError, match="command bits"):
        runner.encode(np.array([1 << 23], np.uint64))


def test_read_output_drops_records_of_a_reset_frame(tmp_path):
    from lodestar.hdl.layouts import trailer_fields

    # a trailer claiming one record (n_records is the last field)
    offset = sum(bits for name, bits in trailer_fields() if name != "n_records")
    trailer = 1 << offset
    (tmp_path / "out.txt").write_text(f"R 1\nT {trailer:x}\nR 2\nX 0\nR 3\n")
    records, trailers = runner.read_output(tmp_path / "out.txt", 8, 4, 12)
    assert len(trailers) == 1 and trailers[0]["n_records"] == 1
    assert [r["n"] for r in records] == [1, 3]
    with pytest.raises(ValueError, match="after the last trailer"):
        runner.group_frames(records, trailers, 8, 4, 12)


def test_run_frames_matches_golden_sequence():
    rng = np.random.default_rng(5)
    frames = [np.where(rng.random((24, 32)) < d, rng.integers(200, 4096, (24, 32)),
                       rng.integers(0, 100, (24, 32))).astype(np.uint16) for d in (0.1, 0.5)]
    cfg = DetectorConfig(width=32, height=24, threshold=150, background=60)
    cfgs = [cfg, cfg.replace(threshold_mode="global", ksigma=1.0)]
    got = runner.run_frames(frames, cfg, cfgs=cfgs)
    golden = Detector(cfg)
    for frame, c, g in zip(frames, cfgs, got):
        golden.configure(c)
        assert g == golden.process(frame)


def test_native_build_plays_as_the_cocotb_build(tmp_path):
    """The native build (``native.cpp`` clocks the harness) writes the same output as the
    cocotb build on a stimulus with register writes, a reset inside a frame, a truncated
    frame and a slow record reader."""
    rng = np.random.default_rng(7)
    frames = [np.where(rng.random((24, 32)) < 0.3, rng.integers(200, 4096, (24, 32)),
                       rng.integers(0, 100, (24, 32))).astype(np.uint16) for _ in range(3)]
    cfg = DetectorConfig(width=32, height=24, threshold=150, background=60)
    gap = runner.frame_gap([cfg])
    stim = runner.Stimulus().reset().registers(cfg.registers()).idle(gap) \
        .frame(frames[0], 2, gap).frame(frames[1], 2, 0, pixels=300).reset(3).idle(gap) \
        .frame(frames[2], 2, gap).frame(frames[0], 2, 0, pixels=500).idle(gap) \
        .frame(frames[1], 2, 4 * gap)
    outputs = []
    for native in (True, False):
        build = runner.Build(32, 24, 12, native=native)
        got = build.simulate(stim, tmp_path / str(native), reader=lambda clock: clock % 5 != 2)
        outputs.append((tmp_path / str(native) / "output.txt").read_text())
    assert outputs[0] == outputs[1]
    records, trailers = got
    assert "X 0" in outputs[0] and records
    assert [t["flags"] & C.FRAME_TRUNCATED for t in trailers] == [0, 0, C.FRAME_TRUNCATED, 0]


def test_golden_set_bit_exact_on_the_native_build(tmp_path):
    """Every committed golden frame, back to back per geometry, on the native build (what
    ``run_frames`` uses): bit-exact with the golden model.  The cocotb build writes what the
    native build writes (``test_native_build_plays_as_the_cocotb_build``) and plays the
    same set with --runslow (``cocotb_tests/test_detector.py``)."""
    from lodestar.hdl.labeller import MIN_HBLANK
    from lodestar.sim.goldenset import load_frame_doc

    by_geometry = {}
    for path in sorted(Path(GOLDEN).glob("*.json")):
        frame, _doc, cfg = load_frame_doc(path)
        by_geometry.setdefault((cfg.width, cfg.height, cfg.pixel_bits), []).append((frame, cfg))
    assert len(by_geometry) >= 3
    for (w, h, bits), pairs in by_geometry.items():
        frames, cfgs = [f for f, _ in pairs], [c for _, c in pairs]
        c = cfgs[0]
        build = runner.Build(w, h, bits, c.label_capacity, c.record_capacity, native=True)
        records, trailers = build.simulate(runner.scenario(frames, cfgs, MIN_HBLANK),
                                           tmp_path / f"{w}x{h}")
        got = runner.group_frames(records, trailers, w, h, bits)
        golden = Detector(c)
        for frame, cfg, g in zip(frames, cfgs, got, strict=True):
            golden.configure(cfg)
            assert g == golden.process(frame), f"{w}x{h}x{bits}: not bit-exact"


def test_every_mask_up_to_4x4_on_the_native_build():
    """All 65536 binary 4x4 images (every smaller image is one of them with dark margins),
    back to back at the minimum blanking, bit-exact with the golden model.  The native
    build plays what the cocotb build plays (``test_native_build_plays_as_the_cocotb_build``)
    at a third of the CPU."""
    rng = np.random.default_rng(44)
    bits = np.arange(1 << 16, dtype=np.uint32)
    masks = ((bits[:, None] >> np.arange(16)) & 1).astype(bool).reshape(-1, 4, 4)
    values = np.where(masks, rng.integers(51, 4096, masks.shape),
                      rng.integers(0, 51, masks.shape)).astype(np.uint16)
    cfg = DetectorConfig(width=4, height=4, threshold=50, background=40)
    got = runner.run_frames(list(values), cfg)
    golden = Detector(cfg)
    wrong = [k for k, (v, g) in enumerate(zip(values, got, strict=True))
             if g != golden.process(v)]
    assert wrong == [], f"{len(wrong)} masks differ, the first {int(bits[wrong[0]]):#06x}"


@pytest.mark.parametrize("ccache", ["/usr/bin/ccache", None])
def test_verilator_env_compiles_through_ccache_where_installed(monkeypatch, tmp_path, ccache):
    """``OBJCACHE`` names ccache when it is installed, its cache in lodestar's unless
    ``CCACHE_DIR`` is set; a second call leaves one of each flag."""
    monkeypatch.setenv("MAKEFLAGS", "OBJCACHE=stale OPT_FAST=-O3 -s")
    monkeypatch.delenv("CCACHE_DIR", raising=False)
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("VERILATOR_ROOT", "")
    monkeypatch.setenv("PATH", os.environ["PATH"])
    monkeypatch.setattr(runner.shutil, "which", lambda name: ccache)
    runner.verilator_env(opt_fast="-O1")
    runner.verilator_env(opt_fast="-O1")
    flags = os.environ["MAKEFLAGS"].split()
    assert "-s" in flags and flags.count("OPT_FAST=-O1") == 1
    assert [f for f in flags if f.startswith("OBJCACHE=")] == (
        [f"OBJCACHE={ccache}"] if ccache else [])
    assert os.environ.get("CCACHE_DIR") == (str(tmp_path / "ccache") if ccache else None)


def test_native_build_reports_a_failed_playback(tmp_path, monkeypatch):
    build = runner.Build(32, 24, 12, native=True)
    frame = np.zeros((24, 32), np.uint16)
    with pytest.raises(ValueError, match="no cocotb test module"):
        build.simulate(runner.Stimulus(), tmp_path, test_module="detector_tb")
    real = runner.encode
    monkeypatch.setattr(runner, "encode", lambda words: real(words)[:-10])   # cut in a run
    with pytest.raises(RuntimeError, match="stimulus ends in a run"):
        build.simulate(runner.Stimulus().reset().frame(frame, 2, 0), tmp_path)


def test_run_frames_refuses_mixed_capacities():
    cfg = DetectorConfig(width=32, height=24)
    frame = np.zeros((24, 32), np.uint16)
    with pytest.raises(ValueError, match="elaboration parameters"):
        runner.run_frames([frame, frame], cfg, cfgs=[cfg, cfg.replace(label_capacity=3)])


def test_cli_golden_frames_bit_exact(capsys):
    assert main(["cosim", f"{GOLDEN}/shape_spiral.json", f"{GOLDEN}/shape_nested_u.json",
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [r["match"] for r in report] == [True, True]
    assert report[0]["records"] >= 1


def test_cli_reports_a_mismatch(monkeypatch, capsys):
    real = runner.run_frames

    def broken(*args, **kwargs):
        results = real(*args, **kwargs)
        results[0].n_blobs += 1
        return results

    monkeypatch.setattr(runner, "run_frames", broken)
    assert main(["cosim", f"{GOLDEN}/shape_spiral.json"]) == 1
    assert "MISMATCH in n_blobs" in capsys.readouterr().out


def test_cli_bad_input(tmp_path, capsys):
    assert main(["cosim", str(tmp_path / "missing.png")]) == 2
    assert "no such file" in capsys.readouterr().err
    np.save(tmp_path / "f.npy", np.zeros((24, 32), np.uint16))
    assert main(["cosim", str(tmp_path / "f.npy")]) == 2
    assert "needs --preset or --config" in capsys.readouterr().err
    (tmp_path / "cfg.json").write_text(json.dumps({"width": 16, "height": 8}))
    assert main(["cosim", str(tmp_path / "f.npy"), "--config", str(tmp_path / "cfg.json")]) == 2
    assert "does not match" in capsys.readouterr().err


@pytest.mark.slow
def test_gate_level_golden_set_bit_exact(capsys):
    """Every committed golden frame through the Yosys netlist (one build per geometry,
    ~1.5 min each), back to back per geometry, bit-exact with the golden model."""
    from lodestar.sim.goldenset import load_frame_doc

    by_geometry = {}
    for path in sorted(Path(GOLDEN).glob("*.json")):
        cfg = load_frame_doc(path)[2]
        by_geometry.setdefault((cfg.width, cfg.height, cfg.pixel_bits), []).append(str(path))
    assert len(by_geometry) >= 2
    for paths in by_geometry.values():
        assert main(["cosim", "--gate-level", *paths, "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        assert len(report) == len(paths) and all(r["match"] for r in report)
