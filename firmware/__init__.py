"""MCU flight software: pure Python that runs unchanged on CPython and MicroPython
(no numpy, typing, dataclasses or itertools).  Layouts come from ``lodestar.contract``."""
