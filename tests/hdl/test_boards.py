"""Board top levels: every board elaborates into a Quartus project with its pins, I/O
standards, clocks and constraints; bad names are refused.  The board fixes of issue 17 are
checked here: fast I/O registers and MISO's output enable in the generated project, sensor
I/O voltages, the DE2-115 LVDS pins against Terasic's QSF, the LVDS receiver's phase and lock,
the SPI clock limit, the registered IRQ, power-up-only reset, and a stalled frame that times
out flagged.  (The top level's behaviour is checked on Verilator in
``cocotb_tests/test_board_top.py``.)"""

import copy
import fnmatch
import gc
import re
import warnings

import pytest
from amaranth import ClockDomain, Module
from amaranth.hdl import UnusedElaboratable
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.firmware.sensor import SENSORS
from lodestar.hdl.boards import (
    BOARDS,
    FRONTENDS,
    IO_STANDARD_VOLTS,
    IRQ_MIN_CLOCKS,
    BoardTop,
    ClockGuard,
    GatewareTop,
    IrqLine,
    SensorReset,
    board_platform,
    project_overrides,
)
from lodestar.hdl.frontend import STALL_TIMEOUT
from lodestar.hdl.spi_slave import MISO_BOARD_NS, MISO_OUT_NS, MISO_TCO_NS


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    """Quartus projects of every board, small frames (the pins and clocks do not depend on
    the frame), as ``{board: {file name: text}}``."""
    out = {}
    for name, board in BOARDS.items():
        small = copy.copy(board)
        small.width, small.height, small.record_capacity, small.record_depth = 16, 8, 4, 4
        top = BoardTop(small)
        plan = board_platform(name).prepare(top, name="lodestar", **project_overrides(board))
        folder = tmp_path_factory.mktemp(name)
        plan.extract(str(folder))
        out[name] = {p.name: p.read_text() for p in folder.iterdir()}
    return out


@pytest.mark.parametrize("name", sorted(BOARDS))
def test_project_files_pins_and_clocks(projects, name):
    board, files = BOARDS[name], projects[name]
    assert {"lodestar.v", "lodestar.qsf", "lodestar.sdc", "build_lodestar.sh"} <= set(files)
    qsf, sdc = files["lodestar.qsf"], files["lodestar.sdc"]
    assert f"set_global_assignment -name DEVICE {board.part}" in qsf
    located = dict(re.findall(r'set_location_assignment -to "([^"]+)" PIN_(\w+)', qsf))
    assert located.pop("clk_osc_0__io") == board.osc_pin
    expected = set()
    for signals in board.pins.values():
        for pins, _direction, _assumed in signals.values():
            expected.update(pins.split())
    assert set(located.values()) == expected       # every board pin, nothing else
    assert qsf.count("io_standard") >= len(located)
    period = 1e9 / board.osc_hz
    assert f'create_clock -name "clk_osc_0__io" -period {period}' in sdc
    assert "derive_pll_clocks" in sdc and "set_clock_groups -asynchronous" in sdc
    verilog = files["lodestar.v"]
    assert "altpll" in verilog
    assert ("altlvds_rx" in verilog) == bool(board.frontend.LVDS_PINS)


def test_boards_are_the_issue_targets():
    assert BOARDS["de2-115"].part == "EP4CE115F29C7" and BOARDS["de2-115"].sensor == "mt9v022"
    assert BOARDS["de0-nano"].part == "EP4CE22F17C6" and BOARDS["de0-nano"].sensor == "mt9p031"
    assert BOARDS["estcube2"].device == "EP4CE22"
    for board in BOARDS.values():
        assert board.pixel_bits in C.SENSOR_PIXEL_BITS.values()
        assert board.sync_hz >= board.pixel_hz     # the pixel crossing's requirement


def test_every_contract_sensor_has_a_front_end():
    """The hdl table covers the contract's sensors exactly, with the contract's widths."""
    assert set(FRONTENDS) == set(C.SENSORS)
    for name, frontend in FRONTENDS.items():
        assert frontend.SENSOR == name
        assert frontend.PIXEL_BITS == C.SENSOR_PIXEL_BITS[name]
    for board in BOARDS.values():
        assert board.frontend is FRONTENDS[board.sensor]


def test_bad_names_are_refused():
    with pytest.raises(ValueError, match="unknown board 'de1'.*de2-115"):
        board_platform("de1")
    with warnings.catch_warnings():       # the refused components are never elaborated
        warnings.simplefilter("ignore", UnusedElaboratable)
        with pytest.raises(ValueError, match="unknown board"):
            BoardTop("de1")
        with pytest.raises(ValueError, match="unknown sensor 'ov7670'.*mt9p031"):
            GatewareTop("ov7670", 16, 8)
        with pytest.raises(ValueError, match="mt9p031 front end has no phase training"):
            GatewareTop("mt9p031", 16, 8, taps=8)
        gc.collect()


# ---- board fixes that simulation or the generated project can show ------------------------

@pytest.mark.parametrize("name", sorted(BOARDS))
def test_fast_io_registers_and_miso_tristate(projects, name):
    """Every sensor input the front end captures has FAST_INPUT_REGISTER (the clock pins and
    the LVDS pins excepted; the SPI inputs go to synchronizers), MISO and IRQ
    FAST_OUTPUT_REGISTER; MISO's buffer has an output enable that the SPI slave's
    ``miso_oe`` (CS low) drives."""
    board, files = BOARDS[name], projects[name]
    qsf, verilog = files["lodestar.qsf"], files["lodestar.v"]
    fast_in = set(re.findall(r'-to "([^"]+?)__io(?:\\\[\d+\])?" -name FAST_INPUT_REGISTER "ON"',
                             qsf))
    fast_out = set(re.findall(r'-to "([^"]+?)__io" -name FAST_OUTPUT_REGISTER "ON"', qsf))
    unregistered = board.frontend.CLOCK_PINS + board.frontend.LVDS_PINS
    inputs = {f"{board.sensor}_0__{sub}"
              for sub, (_pins, direction, _a) in board.pins[board.sensor].items()
              if direction == "i" and sub not in unregistered}
    assert fast_in == inputs
    assert fast_out == {"mcu_0__miso", "mcu_0__irq"}
    miso_buf = re.search(r"module \\lodestar\.pin_mcu_0__miso .*?endmodule", verilog, re.S)
    assert miso_buf and '.use_oe("TRUE")' in miso_buf.group(0)
    assert re.search(r"assign miso_oe = ~ cs_n;", verilog)     # SPIByteSlave: selected


def _module(verilog, name):
    """The text of Verilog module ``lodestar.<name>``."""
    found = re.search(rf"module \\lodestar\.{re.escape(name)} .*?endmodule", verilog, re.S)
    assert found, name
    return found.group(0)


def test_capture_flip_flops_and_forwarded_clock(projects):
    """The MT9P031's D, LINE_VALID and FRAME_VALID go through ``io.FFBuffer``: each port is
    marked ``useioff`` and its flip-flop, clocked by PIXCLK, has no reset (a reset would put
    a multiplexer between the pin and the I/O element's register); EXTCLK (and the
    MT9V022's SYSCLK) leave through a DDR output (altddio_out) clocked by the master clock
    with constant data 1/0; IRQ leaves from an output flip-flop without reset."""
    verilog = projects["de0-nano"]["lodestar.v"]
    for sub in ("d", "line_valid", "frame_valid"):
        assert re.search(rf"\(\* useioff = 32'd1 \*\)\n\s*input (\[\d+:0\] )?"
                         rf"mt9p031_0__{sub}__io;", verilog), sub
        buf = _module(verilog, f"pin_mt9p031_0__{sub}")
        assert re.search(r"always @\(posedge pix_io_clk\)\n\s*\S+ <= \S+;", buf), sub
        assert "rst" not in buf, sub
    for name, sub in (("de0-nano", "mt9p031_0__extclk"), ("de2-115", "mt9v022_0__sysclk")):
        text = projects[name]["lodestar.v"]
        ddr = _module(text, f"pin_{sub}")
        assert "altddio_out" in ddr and ".outclock(master_clk)" in ddr, name
        # the instance's DDR data: bit 0 (rising edge) 1, bit 1 (falling edge) 0
        inst = re.search(rf"\\lodestar\.pin_{sub}  pin_{sub} \((.*?)\);", text, re.S)
        assert re.search(r"\.\\o\$\d+ \(2'h1\)", inst.group(1)), name
    irq = _module(verilog, "pin_mcu_0__irq")
    assert re.search(r"always @\(posedge sync_io_clk\)", irq) and "rst" not in irq


def test_sensor_outputs_within_the_sensor_io_range():
    """No FPGA output reaches a sensor input above the sensor's I/O supply unless a level
    translator is declared for it; the sensor's I/O voltage is within its datasheet range."""
    for board in BOARDS.values():
        low, high = board.frontend.IO_VOLTS
        assert low <= board.sensor_io_volts <= high
        for sub, (_pins, direction, _a) in board.pins[board.sensor].items():
            if direction != "o":
                continue
            volts = IO_STANDARD_VOLTS[board.io_standard[board.sensor]]
            assert volts <= high or sub in board.level_translated, (board.name, sub)
    # the DE0-Nano's 3.3-V GPIO bank is above the MT9P031's 3.1 V maximum
    assert set(BOARDS["de0-nano"].level_translated) == {"extclk", "reset_n"}


# DE2-115 HSMC pins from Terasic's System Builder QSF (independent reference: the LVDS data
# must be on a receiver pair, the clock on a clock input).
_DE2_115_HSMC = {"J27": "HSMC_CLKIN_P1", "J28": "HSMC_CLKIN_N1", "D27": "HSMC_TX_D_P[0]",
                 "D28": "HSMC_TX_D_N[0]", "F24": "HSMC_RX_D_P[0]", "G27": "HSMC_TX_D_P[3]",
                 "G28": "HSMC_TX_D_N[3]", "G25": "HSMC_RX_D_P[3]", "G26": "HSMC_RX_D_N[3]"}


def test_de2_115_lvds_pins_and_standards():
    board = BOARDS["de2-115"]
    sensor = board.pins["mt9v022"]
    assert _DE2_115_HSMC[sensor["ser_data"][0]].startswith("HSMC_RX_D_P")
    assert _DE2_115_HSMC[sensor["ser_clk"][0]].startswith("HSMC_CLKIN_P")
    # single-ended outputs in the HSMC bank use its VCCIO (2.5 V by JP7), not 3.3-V LVTTL
    assert all(_DE2_115_HSMC[sensor[s][0]].startswith("HSMC") for s in ("sysclk", "reset_n"))
    assert board.io_standard["mt9v022"] == "2.5 V"


def test_lvds_receiver_phase_stepped_and_locked(projects):
    """The DE2-115 receiver samples on an ALTPLL whose phase the trainer steps: the PLL's
    dynamic phase-shift ports driven by the stepper (a bit is 16 steps of 208 ps), its reset
    by ReceiverPllReset, and the ALTLVDS_RX in external-PLL mode on its clocks."""
    verilog = projects["de2-115"]["lodestar.v"]
    rx = re.search(r"altlvds_rx #\((.*?)\) \S+ \((.*?)\);", verilog, re.S)
    params, ports = rx.group(1), rx.group(2)
    assert '.use_external_pll("ON")' in params
    assert all(re.search(rf"\.{p}\(\w+", ports) for p in ("rx_inclock", "rx_enable"))
    pll = re.search(r"altpll #\(([^;]*?vco_frequency_control[^;]*?)\) \S+ \((.*?)\);",
                    verilog, re.S)
    params, ports = pll.group(1), pll.group(2)
    assert '.vco_frequency_control("MANUAL_PHASE")' in params
    assert ".vco_phase_shift_step(32'd208)" in params              # 3333 ps / 16 taps
    assert BOARDS["de2-115"].phase_training()["taps"] == 16
    for port in ("phasestep", "phaseupdown", "phasecounterselect", "scanclk", "areset",
                 "phasedone", "locked"):
        assert re.search(rf"\.{port}\(\S+", ports), port


def test_spi_sck_limit_from_the_slave_rule():
    """The slave's limit (``T_sck >= 4 T + t_out``, t_out = clock-to-pin + board + the
    master's tsu(MI)); every board allows the MCU's SCK with a 20 % margin, and MISO, which
    changes at least 2 sync clocks after the SCK edge the master samples on, holds past the
    master's th(MI)."""
    assert MISO_OUT_NS == MISO_TCO_NS + MISO_BOARD_NS + C.MCU_MISO_SETUP_NS
    assert BOARDS["de0-nano"].sync_hz == 75e6
    assert BOARDS["de0-nano"].spi_sck_max_hz == pytest.approx(1e9 / (4e9 / 75e6 + MISO_OUT_NS))
    assert 15e6 < BOARDS["de0-nano"].spi_sck_max_hz < 16e6
    for board in BOARDS.values():
        assert C.MCU_SCK_HZ <= 0.8 * board.spi_sck_max_hz, board.name
        assert 2e9 / board.sync_hz >= C.MCU_MISO_HOLD_NS, board.name


@pytest.mark.parametrize("name", sorted(BOARDS))
def test_master_clock_within_the_sensor_limit(name):
    """The master clock the board's PLL makes (the nearest ratio to ``sensor_clk_hz``, not the
    nominal value: 26.667 MHz once exceeded the MT9V022's 26.6 MHz) is within the sensor's
    ``MASTER_CLOCK_MAX_HZ``, and ``sync`` keeps up with the pixel rate."""
    board = BOARDS[name]
    assert board.master_clock_hz == pytest.approx(board.sensor_clk_hz, rel=0.01)
    assert board.master_clock_hz <= board.frontend.MASTER_CLOCK_MAX_HZ
    assert board.sync_hz >= board.pixel_hz


def _sdc_commands(sdc, command):
    """``(line number, ports or clocks argument, line)`` of each ``command`` line."""
    out = []
    for k, line in enumerate(sdc.splitlines()):
        if line.split(" ", 1)[0] == command:
            found = re.search(r'\[get_(?:ports|keepers|clocks) (?:\{([^}]*)\}|"([^"]*)")\]\s*$',
                              line)
            out.append((k, (found.group(1) or found.group(2)).split() if found else [], line))
    return out


def _covered(port, commands):
    return any(fnmatch.fnmatchcase(port, pattern) for _, patterns, _ in commands
               for pattern in patterns)


@pytest.mark.parametrize("name", sorted(BOARDS))
def test_sdc_constrains_every_clock_and_pin(projects, name):
    """The generated SDC: every clock pin has its ``create_clock`` and every one comes
    before ``derive_pll_clocks`` (a PLL fed by a clock created later is never derived); each
    captured sensor input has an input delay both ways, within half a pixel clock of the
    sampling edge; MISO a maximum and a minimum delay; every other pin an explicit false path
    (synchronized inputs, forwarded clocks, IRQ, RESET_BAR); the Gray pointers of the pixel
    crossing are skew-bounded.  The QSF checks its configuration CRC and reserves unused
    pins."""
    board, files = BOARDS[name], projects[name]
    sdc, qsf = files["lodestar.sdc"], files["lodestar.qsf"]
    created = _sdc_commands(sdc, "create_clock")
    derive = [k for k, line in enumerate(sdc.splitlines()) if line == "derive_pll_clocks"]
    assert len(derive) == 1 and all(k < derive[0] for k, _, _ in created)
    clocks = {"clk_osc_0__io"} | {f"{board.sensor}_0__{sub}__io"
                                  for sub in board.frontend.CLOCK_PINS}
    assert all(_covered(c, created) for c in clocks), created
    ports = set(re.findall(r'set_location_assignment -to "([^"\\]+)', qsf))
    captured = {f"{board.sensor}_0__{sub}__io"
                for sub, (_p, direction, _a) in board.pins[board.sensor].items()
                if direction == "i" and sub not in board.frontend.CLOCK_PINS
                and sub not in board.frontend.LVDS_PINS}
    period = 1e9 / board.pixel_hz
    delays = _sdc_commands(sdc, "set_input_delay")
    for port in captured:
        bounds = {}
        for _, patterns, line in delays:
            if any(fnmatch.fnmatchcase(port, pattern) for pattern in patterns):
                kind, value = re.search(r"-(max|min) (-?[\d.]+)", line).groups()
                bounds[kind] = float(value)
        assert set(bounds) == {"max", "min"}, (port, bounds)
        assert -period / 2 < bounds["min"] < bounds["max"] < period / 2, (port, bounds)
    miso = {"mcu_0__miso__io"}
    assert all(_covered(p, _sdc_commands(sdc, c)) for p in miso
               for c in ("set_max_delay", "set_min_delay"))
    false = _sdc_commands(sdc, "set_false_path")
    rest = ports - clocks - captured - miso
    assert rest and all(_covered(p, false) for p in rest), sorted(
        p for p in rest if not _covered(p, false))
    skews = " ".join(line for _, _, line in _sdc_commands(sdc, "set_max_skew"))
    assert "produce_w_gry" in skews and "consume_r_gry" in skews
    assert "set_global_assignment -name ENABLE_CRC_ERROR_CHECK ON" in qsf
    assert "RESERVE_ALL_UNUSED_PINS_WEAK_PULLUP" in qsf


def test_sdc_check_fails_on_a_bad_constraint_file(projects):
    """The checks above are not vacuous: the DE2-115 SDC with ``derive_pll_clocks`` moved
    first, or without the input delays of the DE0-Nano, or without a false path, fails."""
    sdc = projects["de2-115"]["lodestar.sdc"]
    moved = "derive_pll_clocks\n" + sdc.replace("derive_pll_clocks\n", "")
    created = _sdc_commands(moved, "create_clock")
    derive = [k for k, line in enumerate(moved.splitlines()) if line == "derive_pll_clocks"]
    assert not all(k < derive[0] for k, _, _ in created)
    nano = projects["de0-nano"]["lodestar.sdc"]
    stripped = "\n".join(line for line in nano.splitlines()
                         if not line.startswith("set_input_delay"))
    assert not _covered("mt9p031_0__d__io[3]", _sdc_commands(stripped, "set_input_delay"))
    assert _covered("mt9p031_0__d__io[3]", _sdc_commands(nano, "set_input_delay"))
    no_false = "\n".join(line for line in nano.splitlines() if "extclk" not in line)
    assert not _covered("mt9p031_0__extclk__io", _sdc_commands(no_false, "set_false_path"))


def _sim(dut, bench, domains=("sync",)):
    sim = Simulator(dut)
    for d in domains:
        sim.add_clock(10e-9, domain=d)
    sim.add_testbench(bench)
    sim.run()


def test_irq_is_registered_with_minimum_pulses():
    """Back-to-back packets (busy low for one clock) give one rising edge each and a low
    pulse of IRQ_MIN_CLOCKS; irq changes only on a clock edge after busy did."""
    dut = IrqLine()
    busy = ([0] * 5 + [1] * 40 + [0] + [1] * 30 + [0] * 3 + [1] * 25 + [0] * 40)
    trace = []

    async def bench(ctx):
        for b in busy:
            ctx.set(dut.busy, b)
            trace.append(ctx.get(dut.irq))     # before the edge: still the old level
            await ctx.tick()

    _sim(dut, bench)
    rises = [t for t in range(1, len(trace)) if trace[t] and not trace[t - 1]]
    assert len(rises) == 3                            # one rising edge per packet
    assert rises[:2] == [6, 46 + IRQ_MIN_CLOCKS]      # the 1-clock low stretched
    runs, t = [], 0
    while t < len(trace):
        u = t
        while u < len(trace) and trace[u] == trace[t]:
            u += 1
        runs.append((trace[t], u - t))
        t = u
    assert all(n >= IRQ_MIN_CLOCKS for _, n in runs[1:-1])
    assert trace[5] == 0 and trace[6] == 1            # one clock after busy rose


def test_clock_guard_qualifies_lock_and_counts_losses():
    """``qualified`` rises only after ``locked`` stayed high for ``qualify_clocks`` clocks (a
    chattering lock restarts the wait), falls right after a loss (each loss of a qualified
    lock steps the Gray count ``losses`` by one bit), and rises again only after a new
    qualified lock; ``ever_qualified`` rises with the first and stays up."""
    guard = ClockGuard(qualify_clocks=5)
    top = Module()
    top.domains.osc = ClockDomain("osc", reset_less=True)
    top.submodules.guard = guard
    locked = [0] * 3 + [1] * 3 + [0] + [1] * 10 + [0] * 2 + [1] * 4 + [0] + [1] * 10
    seen = []

    async def bench(ctx):
        for level in locked:
            ctx.set(guard.locked, level)
            await ctx.tick("osc")
            seen.append((ctx.get(guard.qualified), ctx.get(guard.ever_qualified),
                         ctx.get(guard.losses)))

    _sim(top, bench, domains=("osc",))
    qualified = [q for q, _, _ in seen]
    # locked reaches the guard 2 clocks late (synchronizer); 5 clocks of lock before release
    assert qualified.index(1) == 7 + 2 + 4
    assert [e for _, e, _ in seen][13:] == [1] * (len(seen) - 13)
    runs = "".join(map(str, qualified))
    # the 4-clock lock after the loss is not enough; the last one is
    assert runs == "0" * 13 + "1" * 6 + "0" * 11 + "1" * 4, runs
    codes = [g for _, _, g in seen]
    assert [(a, b) for a, b in zip(codes, codes[1:]) if a != b] == [(0, 1)]


def test_sensor_reset_holds_reset_bar_with_the_clock_running():
    """RESET_BAR is low at power-up until ``clocks`` clocks with the master clock running
    have passed (a clock break restarts the count); a request pulls it low at once and it
    stays low ``clocks`` clocks after the request ends; a clock loss while it is high does
    not touch it."""
    dut = SensorReset(clocks=6)
    top = Module()
    top.domains.osc = ClockDomain("osc", reset_less=True)
    top.submodules.dut = dut
    # (request, clock_ok) per clock
    steps = ([(0, 0)] * 3 + [(0, 1)] * 4 + [(0, 0)] + [(0, 1)] * 8 + [(0, 0)] * 3
             + [(0, 1)] * 3 + [(1, 1)] + [(0, 1)] * 9)
    levels = []

    async def bench(ctx):
        for request, clock_ok in steps:
            ctx.set(dut.request, request)
            ctx.set(dut.clock_ok, clock_ok)
            await ctx.tick("osc")
            levels.append(ctx.get(dut.reset_n))

    _sim(top, bench, domains=("osc",))
    trace = "".join(map(str, levels))
    # power-up: the 4 clocks with the clock running before the break do not count
    assert trace[:14] == "0" * 14 and trace[14:22] == "1" * 8, trace
    # the clock loss while high: still high; the 1-clock request: low for 1 + 6 clocks
    assert trace[22:] == "0" * 7 + "1" * 3, trace


def _pix_frame(rows, cut=None, hblank=4):
    """``(d, lv, fv)`` samples of a frame of ``rows``; with ``cut``, the sensor stops for good
    after that many pixels (FRAME_VALID stays high, nothing more)."""
    out = [(0, 0, 0)] * 6 + [(0, 0, 1)] * 2
    sent = 0
    for row in rows:
        for p in row:
            if cut is not None and sent == cut:
                return out
            out.append((p, 1, 1))
            sent += 1
        out += [(0, 0, 1)] * hblank
    return out + [(0, 0, 0)] * 4


@pytest.mark.parametrize("rows_sent", [2, 1.625])
def test_stalled_frame_times_out_flagged_and_clock_loss_is_flagged(rows_sent):
    """GatewareTop with a short stall timeout: the MT9P031 stops inside a frame (after its
    second row, or inside it with LINE_VALID low: the front end then ends that row short);
    the detector still ends the frame (busy falls) and its trailer has FRAME_TIMEOUT (and
    FRAME_LINE_ERROR for the short row; else it counts the star it saw); the next frame's
    trailer has no flag.  A PLL lock loss (``pll_losses`` step) raises OVF_CLOCK_LOST."""
    w, h = 8, 4
    top = GatewareTop("mt9p031", w, h, record_capacity=4, record_depth=4, stall_timeout=300)
    star = [[0] * w for _ in range(h)]
    star[1][2] = star[1][3] = 4000
    samples = _pix_frame(star, cut=int(rows_sent * w)) + [(0, 0, 1)] * 2000 + _pix_frame(star)
    samples += [(0, 0, 0)] * 400
    trailers, busy_after_stall, overflow = [], [], []

    async def sensor(ctx):
        for d, lv, fv in samples:
            ctx.set(top.pix_d, d)
            ctx.set(top.line_valid, lv)
            ctx.set(top.frame_valid, fv)
            await ctx.tick("pix")
        busy_after_stall.append(ctx.get(top.detector.busy))
        overflow.append(ctx.get(top.spi.overflow))
        ctx.set(top.pll_losses, 1)
        await ctx.tick("pix").repeat(4)
        overflow.append(ctx.get(top.spi.overflow))

    async def packets(ctx):
        tr = top.packetizer.trailer
        while True:
            await ctx.tick()
            # nobody reads the packets: the first trailer is taken, the second stays offered
            if ctx.get(tr.valid) and (not trailers or trailers[-1]["frame_counter"]
                                      != ctx.get(tr.payload.frame_counter)):
                trailers.append({k: ctx.get(getattr(tr.payload, k))
                                 for k in ("flags", "n_blobs", "frame_counter")})

    sim = Simulator(top)
    sim.add_clock(10e-9)
    sim.add_clock(10.4e-9, domain="pix")
    sim.add_testbench(sensor)
    sim.add_testbench(packets, background=True)
    sim.run()
    assert [t["frame_counter"] for t in trailers] == [0, 1]
    if rows_sent == 2:
        assert trailers[0]["flags"] == C.FRAME_TIMEOUT and trailers[0]["n_blobs"] == 1
    else:
        assert trailers[0]["flags"] == C.FRAME_TIMEOUT | C.FRAME_TRUNCATED | C.FRAME_LINE_ERROR
    assert trailers[1]["flags"] == 0 and trailers[1]["n_blobs"] == 1
    assert busy_after_stall == [0]
    assert [(o >> C.OVF_CLOCK_LOST) & 1 for o in overflow] == [0, 1]


def test_default_stall_timeout_outlasts_any_row_blanking():
    """The watchdog never fires inside a frame the sensor is still sending: its default
    timeout is over 100 times the longest horizontal blanking the sensor can be programmed
    for (the MCU set-up's limit), at each board's clocks."""
    for board in BOARDS.values():
        longest_gap_s = SENSORS[board.sensor]["hblank"][2] / board.pixel_hz
        assert STALL_TIMEOUT / board.sync_hz > 100 * longest_gap_s, board.name
