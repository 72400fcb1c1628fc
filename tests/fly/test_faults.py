"""Fault schedules: names checked, windows spaced, one-shots fire once, the ground's command
out of SAFE, a corrupt database and the recovery figures."""

import pytest

from lodestar.firmware import executive
from lodestar.fly import faults


def test_windows_and_one_shots():
    with pytest.raises(ValueError, match="--faults 'gremlin'"):
        faults.Schedule(["gremlin"])
    s = faults.Schedule(["miso-flip", "truncated", "db-crc"], fault_frame=4)
    assert s.windows["miso-flip"] == pytest.approx((0.4, 0.7))
    assert s.windows["truncated"] == pytest.approx((1.9, 2.0))
    assert s.windows["db-crc"] == (0.0, 0.0) and s.has("db-crc") and not s.has("pll-loss")
    assert s.active("miso-flip", 0.5) and not s.active("miso-flip", 0.71)
    assert not s.active("truncated", 1.95)                 # a one-shot is not a window
    assert s.starting(1.0) is None and s.starting(1.95) == "truncated"
    assert s.starting(3.0) is None


class _Exe:
    def __init__(self, reason):
        self.state, self.reason, self.commands = executive.SAFE, reason, []

    def command(self, code, arg=None, value=None):
        self.commands.append((code, arg))


class _Twin:
    def __init__(self, reason):
        self.exe = _Exe(reason)


def test_ground_starts_a_safe_tracker_again_after_a_second():
    s = faults.Schedule([])
    twin = _Twin("database: CRC")
    s.ground(twin, 1.0)
    s.ground(twin, 1.5)
    assert twin.exe.commands == []
    s.ground(twin, 2.0)
    assert twin.exe.commands == [(executive.CMD_DATABASE, 1),
                                 (executive.CMD_MODE, executive.MODE_AUTO)]


def test_corrupt_flips_one_byte(tmp_path):
    path = tmp_path / "db.lsdb"
    path.write_bytes(bytes(100))
    bad = faults.corrupt(path)
    assert len(bad) == 100 and sum(b != 0 for b in bad) == 1


def test_recovery_counts_periods_to_the_next_tracking_solve():
    s = faults.Schedule(["irq-stuck-high"], fault_frame=10)      # 1.0 .. 1.3 s
    rows = [{"t_s": 1.05, "status": "OK", "mode": "TRACK", "faults": ["irq-stuck-high"]},
            {"t_s": 1.5, "status": "IRQ_TIMEOUT", "mode": "COAST", "faults": []},
            {"t_s": 1.51, "status": "OK", "mode": "TRACK", "faults": []}]
    rec = faults.recovery(rows, s)["irq-stuck-high"]
    assert rec["frames_to_recovery"] == 3 and rec["recovered_s"] == 1.51 and rec["within"]
    rows[2]["t_s"] = 1.71
    assert not faults.recovery(rows, s)["irq-stuck-high"]["within"]


def test_recovery_of_a_one_shot_counts_from_the_step_it_acted_in():
    """The watchdog hang acts in a step after its start and that step still solves: the
    recovery is the next tracking solve after it."""
    s = faults.Schedule(["watchdog"], fault_frame=10)           # 1.0 .. 1.1 s
    rows = [{"t_s": 1.2, "status": "OK", "mode": "TRACK", "faults": []},
            {"t_s": 3.8, "status": "OK", "mode": "TRACK", "faults": ["watchdog"]},
            {"t_s": 3.8, "status": "NO_FRAME", "mode": "CONFIGURE", "faults": []},
            {"t_s": 4.25, "status": "OK", "mode": "TRACK", "faults": []}]
    rec = faults.recovery(rows, s)["watchdog"]
    assert rec["end_s"] == 3.8 and rec["recovered_s"] == 4.25 and rec["frames_to_recovery"] == 5
