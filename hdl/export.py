"""Verilog export of lodestar components for co-simulation and synthesis."""

from amaranth import Signal
from amaranth.back import verilog


def ports(component):
    """Every signal of the component's signature, in signature order (constant members such
    as an ``always_ready`` stream's ``ready`` are not ports)."""
    out = []
    for _path, _member, value in component.signature.flatten(component):
        value = value.as_value() if hasattr(value, "as_value") else value
        if isinstance(value, Signal):
            out.append(value)
    return out


def to_verilog(component, name):
    """Verilog text of ``component`` as module ``name`` (clock ``clk``, sync reset ``rst``)."""
    return verilog.convert(component, name=name, ports=ports(component))
