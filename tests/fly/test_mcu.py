"""The MCU time model: per frame class, from the docs' F401 estimates, spent on the twin's
clock around the real ``process``; the executive's share derived from the units measured on
the Cortex-M4F build, which ``docs/mcu_board.md`` reports."""

import re
from pathlib import Path

import pytest

from lodestar.fly import mcu


class _Result:
    n_records = 10


class _Tracker:
    settings, status, reason = "settings", 0, ""

    def process(self, packet, prior=None, omega=None, dt=None):
        return _Result()

    def prefetch(self, prior=None, omega=None, dt=None):
        self.hooked = (prior, omega, dt)
        return 0


def test_classes():
    assert mcu.process_ms(_Result(), None, None) == mcu.LIS_REST_MS
    assert mcu.process_ms(_Result(), None, (0.0, 0.01, 0.0)) == mcu.LIS_MOVING_MS
    # the docs' budgeted tracking frame (10 records, 73 ms) and every blob (50, 243 ms)
    assert mcu.process_ms(_Result(), (0, 0, 0, 1), None) == pytest.approx(73, abs=0.5)
    fifty = _Result()
    fifty.n_records = 50
    assert mcu.process_ms(fifty, (0, 0, 0, 1), None) == pytest.approx(243, abs=0.5)


def test_timed_tracker_spends_the_time_and_a_hang_once():
    spent = []
    t = mcu.TimedTracker(_Tracker(), spent.append)
    assert t.settings == "settings" and t.status == 0
    t.hang_ms = 3000
    t.process(b"", prior=(0, 0, 0, 1))
    t.process(b"", prior=(0, 0, 0, 1))
    assert spent == [pytest.approx(73 + mcu.LOOP_MS + 3000, abs=0.5),
                     pytest.approx(73 + mcu.LOOP_MS, abs=0.5)]


def test_the_hook_is_passed_on_and_spends_its_collection_with_a_prior():
    spent = []
    inner = _Tracker()
    t = mcu.TimedTracker(inner, spent.append)
    assert t.prefetch(None) == 0 and inner.hooked == (None, None, None) and spent == []
    assert t.prefetch((0, 0, 0, 1), (0.0, 0.0, 0.01), 0.1) == 0
    assert inner.hooked == ((0, 0, 0, 1), (0.0, 0.0, 0.01), 0.1)
    assert spent == [mcu.HOOK_MS]


def test_loop_ms_is_the_measured_step_and_min_sum():
    """``LOOP_MS`` is the sum of the two measured figures (the gyro ring's sample in the
    step), each the units ``docs/mcu_board.md`` reports with the F401 estimate it prints."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "mcu_board.md").read_text()
    rows = {"step": r"\| one executive step around a `process`[^|]*\| ([\d,]+) \| "
                    r"([\d.]+) ms",
            "min_sum": r"\| the same with `min_sum` written back \| \+([\d,]+) \| \+([\d.]+) ms"}
    for name, pattern in rows.items():
        units, ms = re.search(pattern, doc).groups()
        assert mcu.STEP_UNITS[name] == int(units.replace(",", ""))
        assert mcu.f401_ms(mcu.STEP_UNITS[name]) == pytest.approx(float(ms), abs=0.05)
    ref = re.search(r"\(([\d,]+) and ([\d,]+) units: ", doc).groups()
    assert tuple(mcu.REFERENCE_UNITS.values()) == tuple(int(u.replace(",", "")) for u in ref)
    assert mcu.LOOP_MS == pytest.approx(mcu.f401_ms(2837 + 447))
    assert 10.3 < mcu.LOOP_MS < 10.5
