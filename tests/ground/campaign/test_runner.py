"""``lodestar campaign``: tiny campaigns on the lohmann preset (fast frames) check the
determinism across worker counts, the journal and resume, the files written and the bad
arguments."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lodestar.cli import main
from lodestar.ground.campaign import runner, trials


def rate_config(**changes):
    config = runner.make_config("rate", ["lohmann"], seed=3, rates=[0.0, 1.0])
    config.update(changes)
    return config


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """A complete two-rate, two-trial campaign run in this process."""
    out = tmp_path_factory.mktemp("reference")
    rows, paths = runner.run_campaign(rate_config(), 2, str(out), workers=1, progress=False)
    return out, rows, paths


def journal_results(out):
    return runner.read_journal(os.path.join(out, runner.JOURNAL))[1]


def test_files_written(reference):
    out, rows, paths = reference
    assert sorted(os.path.basename(p) for p in paths) == [
        "campaign_rate.csv", "campaign_rate.json", "campaign_rate.png"]
    assert all(os.path.getsize(p) > 0 for p in paths)
    with open(out / "campaign_rate.png", "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    with open(out / "campaign_rate.csv") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["preset"], float(r["rate_deg_s"])) for r in table] == [("lohmann", 0.0),
                                                                     ("lohmann", 1.0)]
    summary = json.loads((out / "campaign_rate.json").read_text())
    assert summary["table"] == json.loads(json.dumps(rows))
    assert summary["trials_per_level"] == 2
    assert summary["references"]["dzamba_table_4_1"]["1"] == [99.4, 96.8]
    for row in rows:
        assert row["trials"] == row["right"] + row["wrong"] + row["failed"] == 2
    assert rows[1]["dzamba_st16_n3_pct"] == 96.8 and rows[0]["dzamba_st16_n3_pct"] is None
    assert len(journal_results(out)) == 4


def test_same_results_with_two_workers(reference, tmp_path):
    out, rows, _paths = reference
    rows2, _ = runner.run_campaign(rate_config(), 2, str(tmp_path), workers=2,
                                     progress=False)
    assert rows2 == rows
    assert journal_results(tmp_path) == journal_results(out)


def test_resume_runs_only_the_missing_tasks(reference, tmp_path, monkeypatch, capsys):
    out, rows, _paths = reference
    assert runner.run_campaign(rate_config(), 2, str(tmp_path), max_tasks=3,
                                 progress=False) == (None, [])
    assert "3 tasks; 1 remain" in capsys.readouterr().err
    assert len(journal_results(tmp_path)) == 3
    with open(tmp_path / runner.JOURNAL, "a") as fh:      # a write the kill cut short
        fh.write('{"key": "rate/lohmann/1/1", "resu')
    ran = []
    real = trials.run_task

    def counting(task, config):
        ran.append(trials.task_key(task))
        return real(task, config)

    monkeypatch.setattr(trials, "run_task", counting)
    rows2, paths = runner.run_campaign(rate_config(), 2, str(tmp_path), resume=True,
                                         progress=False)
    assert len(ran) == 1 and rows2 == rows and paths
    assert "resuming: 3 of 4 tasks" in capsys.readouterr().err
    assert journal_results(tmp_path) == journal_results(out)


def test_existing_journal_needs_resume_and_the_same_settings(reference, tmp_path):
    out, _rows, _paths = reference
    with pytest.raises(ValueError, match="pass --resume"):
        runner.run_campaign(rate_config(), 2, str(out), progress=False)
    with pytest.raises(ValueError, match="seed differ"):
        runner.run_campaign(rate_config(seed=4), 2, str(out), resume=True, progress=False)
    (tmp_path / runner.JOURNAL).write_text('{"campaign": {}}\nnot json\n{"key": 1}\n')
    with pytest.raises(ValueError, match="line 2 is not a result"):
        runner.read_journal(str(tmp_path / runner.JOURNAL))


@pytest.mark.parametrize("last", ["junk line\n", '{"key": "x"}\n', "[1, 2]\n", '"text"\n',
                                  '{"key": "rate/lohmann/1/1", "resu'])
def test_a_bad_last_line_is_repaired_and_resume_works_again(reference, tmp_path, last):
    """Issue 19, item 7: a last line that is not a result (junk, valid JSON of another shape,
    a write cut short) is cut from the journal on resume, so the next resume works too and
    no result is lost."""
    out, rows, _paths = reference
    assert runner.run_campaign(rate_config(), 2, str(tmp_path), max_tasks=2,
                                 progress=False) == (None, [])
    journal = tmp_path / runner.JOURNAL
    good = journal.read_bytes()
    with open(journal, "a") as fh:
        fh.write(last)
    assert runner.run_campaign(rate_config(), 2, str(tmp_path), resume=True,
                                 max_tasks=1, progress=False) == (None, [])
    assert journal.read_bytes().startswith(good) and last not in journal.read_text()
    rows2, paths = runner.run_campaign(rate_config(), 2, str(tmp_path), resume=True,
                                         progress=False)
    assert rows2 == rows and paths
    assert journal_results(tmp_path) == journal_results(out)


def test_every_study_writes_its_table(tmp_path):
    """Each other study on one lohmann frame per level (the falsestars levels reduced)."""
    for study, levels in (("accuracy", None), ("limiting", ["2"]), ("falsestars", ["false=3"])):
        config = runner.make_config(study, ["lohmann"], seed=1, quick=True)
        if levels:
            config["levels"] = levels
        rows, paths = runner.run_campaign(config, 1, str(tmp_path / study), progress=False)
        assert all(os.path.getsize(p) > 0 for p in paths) and len(paths) == 3
        assert rows and all(r["preset"] == "lohmann" for r in rows)
        assert runner.format_table(study, rows).count("\n") == len(rows)
    assert {r["method"] for r in rows} == set(trials.METHODS)


def test_cli_quick_campaign(tmp_path, capsys):
    out = tmp_path / "cli"
    args = ["campaign", "rate", "--quick", "--presets", "lohmann", "--rates", "0",
            "--out", str(out), "--workers", "1", "--no-progress"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "availability_pct" in text and "campaign_rate.png" in text
    assert main(args) == 2                                   # the journal exists
    assert "pass --resume" in capsys.readouterr().err
    assert main(args + ["--resume"]) == 0


@pytest.mark.parametrize("args, message", [
    (["rate", "--trials", "0"], "--trials must be a positive integer"),
    (["rate", "--rates", "-1"], "--rates must be distinct numbers"),
    (["rate", "--rates", "1", "1"], "--rates must be distinct numbers"),
    (["rate", "--rates", "45"], "--rates must be distinct numbers in 0..30 "),
    (["rate", "--axis", "roll", "--rates", "400"], "--rates must be distinct numbers in 0..360 "),
    (["accuracy", "--rates", "1"], "--rates applies to the rate and limiting studies"),
    (["rate", "--workers", "0"], "--workers must be a positive integer"),
    (["rate", "--max-tasks", "0"], "--max-tasks must be a positive integer"),
    (["rate", "--seed", "-2"], "--seed must be a non-negative integer"),
])
def test_bad_arguments(args, message, tmp_path, capsys):
    assert main(["campaign"] + args + ["--out", str(tmp_path), "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_a_roll_may_spin_faster_than_a_slew():
    """Up to 360 deg/s about the boresight (the E-sail's first spin), 30 about other axes."""
    config = runner.make_config("rate", ["estcube2"], rates=[20.0, 45.0, 360.0], axis="roll")
    assert config["levels"] == ["20", "45", "360"] and config["axis"] == "roll"
    for axis in ("cross", "random"):
        with pytest.raises(ValueError, match=r"0\.\.30 deg/s"):
            runner.make_config("rate", ["estcube2"], rates=[45.0], axis=axis)


def test_unknown_study_or_preset_is_an_argparse_error(capsys):
    for args in (["campaign", "nope"], ["campaign", "rate", "--presets", "nope"]):
        with pytest.raises(SystemExit) as exc:
            main(args)
        assert exc.value.code == 2
    capsys.readouterr()


def _children(pid):
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGTERM])
def test_workers_end_with_the_campaign(tmp_path, how):
    """Issue 19, item 4: ``kill -9`` or SIGTERM of a ``--workers 2`` campaign leaves no
    worker behind; SIGTERM stops it as Ctrl-C does (exit 130, the journal kept)."""
    out = tmp_path / "c"
    proc = subprocess.Popen([sys.executable, "-m", "lodestar", "campaign", "rate", "--presets",
                             "lohmann", "--trials", "50", "--out", str(out), "--workers", "2",
                             "--no-progress"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        workers = []
        while len(workers) < 2 and time.monotonic() < deadline:
            time.sleep(0.5)
            workers = [p for p in _children(proc.pid) if _alive(p)]
        assert len(workers) >= 2, "the workers did not start"
        proc.send_signal(how)
        code = proc.wait(timeout=60)
        if how == signal.SIGTERM:
            assert code == 130 and "--resume" in proc.stderr.read()
            assert (out / runner.JOURNAL).is_file()
        deadline = time.monotonic() + 15
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not [p for p in workers if _alive(p)]
    finally:
        if proc.poll() is None:
            proc.kill()


def test_fov_study_writes_its_table(tmp_path, capsys):
    """The ``fov`` study on two of its fields, one estcube2-sensor frame each, through the
    command line (the 5 deg database takes a minute to build: the campaign in docs/)."""
    config = runner.make_config("fov", ["estcube2"], seed=2)
    assert config["levels"] == [f"{f:g}" for f in trials.FOVS_DEG]
    config["levels"] = ["20", "40"]
    rows, paths = runner.run_campaign(config, 1, str(tmp_path), progress=False)
    assert sorted(os.path.basename(p) for p in paths) == [
        "campaign_fov.csv", "campaign_fov.json", "campaign_fov.png"]
    assert [(r["fov_deg"], r["trials"], r["wrong"]) for r in rows] == [(20.0, 1, 0),
                                                                      (40.0, 1, 0)]
    assert rows[0]["db_stars"] > rows[1]["db_stars"] and rows[0]["aperture_mm"] > \
        rows[1]["aperture_mm"]
    assert rows[0]["fov_v_deg"] == pytest.approx(15.07, abs=0.01)
    text = runner.format_table("fov", rows)
    assert text.count("\n") == 2 and "solve_ms_p95" in text
