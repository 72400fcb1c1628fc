"""The FPGA->MCU interface, one source for the gateware, the golden models, the ground tools
and the MCU firmware: detection limits, widths and registers (:mod:`.detection`), the
packet (:mod:`.packet`), the SPI link (:mod:`.link`) and the star-database layout
(:mod:`.stardb`).  Pure Python that runs unchanged on CPython and MicroPython; the
semantics are in ``docs/contract.md``.  ``from lodestar import contract as C`` gives every
name of the first three."""

from lodestar.contract.detection import *  # noqa: F403
from lodestar.contract.integers import *  # noqa: F403
from lodestar.contract.link import *  # noqa: F403
from lodestar.contract.packet import *  # noqa: F403
