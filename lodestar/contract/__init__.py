"""The FPGA->MCU interface, one source for the gateware, the golden models, the ground tools
and the MCU firmware: detection limits, widths and registers (:mod:`.detection`), the
packet (:mod:`.packet`), the SPI link (:mod:`.link`) and the star-database layout
(:mod:`.stardb`).  Pure Python that runs unchanged on CPython and MicroPython; the
semantics are in ``docs/contract.md``.  ``from lodestar import contract as C`` gives every
public name of the first three and :mod:`.integers` (``C.X``, ``from lodestar.contract
import X``), resolved on first use by the module's ``__getattr__`` and then kept: the
package holds no copy of the names nobody reads, which is heap on the MCU (the flight
firmware imports the submodules themselves; ``docs/mcu_board.md``, Heap and stack)."""

_SUBMODULES = ("packet", "detection", "integers", "link")
"""Where a name is looked for, in this order: the link last, so that reading the packet's and
the detection's names does not import it (a name in two of them is the same object)."""
_MODULES = ("detection", "integers", "link", "packet", "stardb", "telemetry")
"""The package's submodules: a name of one is imported, never looked for in the others
(MicroPython's ``from lodestar.contract import stardb`` asks :func:`__getattr__` first)."""


def __getattr__(name):
    """The submodule ``name`` (:data:`_MODULES`), or the public ``name`` of a submodule of
    :data:`_SUBMODULES`, kept in the package for the next read; ``AttributeError`` if none
    has it (PEP 562, MicroPython's ``MICROPY_MODULE_GETATTR``)."""
    if name in _MODULES:
        return __import__("lodestar.contract." + name, None, None, (name,))
    if name[:1] != "_":
        for sub in _SUBMODULES:
            module = __import__("lodestar.contract." + sub, None, None, (name,))
            if hasattr(module, name):
                value = getattr(module, name)
                globals()[name] = value
                return value
    raise AttributeError(name)
