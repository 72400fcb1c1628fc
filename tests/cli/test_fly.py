"""``lodestar fly``: bad arguments exit 2 with one line; a short run on the golden engine
(slow: full estcube2 frames) writes its telemetry, plot and JSON and exits 0."""

import json

import pytest

from lodestar.cli import main


@pytest.mark.parametrize("argv, says", [
    (["--preset", "lohmann"], "MT9P031"),
    (["--frames", "0"], "--frames 0"),
    (["--trajectory", "rest", "--rate", "0", "1", "0"], "--trajectory rest"),
    (["--ramp", "-1"], "--ramp"),
])
def test_bad_arguments_exit_2_with_one_line(argv, says, capsys):
    assert main(["fly", "--engine", "golden", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and err[0].startswith("lodestar fly: error:")


def test_out_must_be_a_folder_and_faults_known(tmp_path, capsys):
    afile = tmp_path / "file"
    afile.write_text("mine")
    assert main(["fly", "--engine", "golden", "--out", str(afile)]) == 2
    assert afile.read_text() == "mine"
    with pytest.raises(SystemExit) as exc:
        main(["fly", "--faults", "gremlin"])
    assert exc.value.code == 2


@pytest.mark.slow
def test_short_golden_run_writes_everything(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["fly", "--engine", "golden", "--frames", "4", "--out", str(out),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["engine"] == "golden" and doc["mcu"] == "cpython"
    solved = [f for f in doc["frames"] if f["status"] == "OK"]
    assert solved and all(f["error_arcsec"] < 60 for f in solved)
    assert {p.name for p in out.iterdir()} == {"telemetry.csv", "telemetry.json", "fly.png"}
