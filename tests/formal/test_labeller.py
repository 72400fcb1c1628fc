"""Formal: the labeller's internal bounds hold for any pixel stream on small frames (BMC).

``hdl.labeller.Labeller`` raises its sticky ``fault`` if a bound it is sized for is
exceeded: a feature slot allocated with none left, the component stack spilled past
``max_stack(width)``, the stack not empty at a row end.  For any stream of beats (any
coordinates, ``lit`` and ``eof``, valid on any clock, the feature engine busy at any time,
resets at any time) ``fault`` stays low for ``DEPTH`` clocks: more than a whole 3x2 frame,
its vertical blanking and the start of the next.  Pixel values and weights are held at 0:
they do not steer the labeller (they only ride along in its ops).  Mutation: a labeller
whose push stage never pushes faults.  Opt-in (``--runslow``):
the proof takes ~2.5 min on this machine, the mutant a few seconds.
"""

import pytest
from amaranth import Elaboratable, Module
from amaranth.hdl import Assert, Assume

from lodestar.hdl.labeller import Labeller

from .sby import available, prove

pytestmark = [pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing"),
              pytest.mark.slow]

W, H, CAPACITY, DEPTH = 3, 2, 2, 22


class BoundedLabeller(Elaboratable):
    def __init__(self, labeller):
        self.labeller = labeller

    def elaborate(self, platform):
        m = Module()
        m.submodules.labeller = lab = self.labeller
        m.d.comb += [Assume(lab.pixels.payload.data == 0),
                     Assume(lab.pixels.payload.weight == 0),
                     Assert(~lab.fault)]
        return m


class ForgetfulLabeller(Labeller):
    """Mutant: the push stage never pushes a previous-row component on the stack."""

    def _push(self, m, above):
        top, second, _push = super()._push(m, above)
        return top, second, 0


def inputs(lab):
    return [lab.pixels.valid, lab.pixels.payload.as_value(), lab.feat_busy]


def test_labeller_bounds(tmp_path):
    lab = Labeller(W, H, 12, CAPACITY)
    result = prove(BoundedLabeller(lab), "bmc", DEPTH, tmp_path, ports=inputs(lab))
    assert result.passed, result.log


def test_labeller_bounds_mutant_fails(tmp_path):
    lab = ForgetfulLabeller(W, H, 12, CAPACITY)
    result = prove(BoundedLabeller(lab), "bmc", DEPTH, tmp_path, ports=inputs(lab))
    assert result.failed, result.log
