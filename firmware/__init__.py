"""MCU flight software: pure Python that runs unchanged on CPython and MicroPython
(no numpy, typing, dataclasses or itertools).  Layouts come from ``lodestar.contract``.

On MicroPython the package's import sets ``gc.threshold`` to :data:`IMPORT_GC_THRESHOLD`:
the firmware's imports (and the objects a flight loop makes before its tracker) then
collect every few KB, so that the module globals they keep fill the holes the imports'
temporaries leave instead of spreading over the heap, and a lost-in-space frame finds its
free heap in larger pieces (``docs/mcu_board.md``, Heap and stack).  Each
:class:`lodestar.firmware.pipeline.StarTracker` sets its own threshold."""

import gc
import sys

IMPORT_GC_THRESHOLD = 4096
"""Bytes allocated between collections while the firmware is imported (MicroPython only)."""

if sys.implementation.name == "micropython":
    gc.threshold(IMPORT_GC_THRESHOLD)
