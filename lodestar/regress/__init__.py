"""Firmware regression: recorded FPGA packets replayed through the flight API on CPython,
on the flight MCU's own build and on MicroPython's WebAssembly port.
:mod:`.mcu` and :mod:`.loop` are the replay that runs in the MCU image (MicroPython-safe, frozen
into it), :mod:`.replay` loads a set and compares, :mod:`.record` regenerates it,
:mod:`.micropython` runs the WebAssembly port, :mod:`.qemu` the MCU reference: MicroPython for
a Cortex-M4F with the STM32F401's memory map on QEMU, the set frozen into flash (with
:mod:`.qemuloop`, its loop, :mod:`.linkmodel`, the gateware's side of the SPI link for the
executive, :mod:`.fram`, the star database's F-RAM chip, and :mod:`.semihost`, host files),
:mod:`.unixport` the float32 unix-port build (floats in the object word, the firmware frozen:
heap bisection, instruction counts) and :mod:`.mcutime` the F401 time estimate from it (with
:mod:`.perfbench`; :mod:`.reprprobe` tells a build's object representation).

A set is a folder with ``packets/NAME.bin`` and ``manifest.json`` (``format`` 2,
:data:`.replay.SET_FORMAT`): ``tolerances`` (double comparisons), ``float32`` (``build``,
``tolerances``: the float32 build against its own outcomes, ``bound``: its outcomes against
the double ones), ``methods``, ``databases`` (recipes and SHA-256 of the star databases),
``cameras`` and ``cases``, each with its packet, ``inputs``, ``truth`` and per method
``expected`` (double precision), ``expected_float32`` (the float32 build) and
``error_arcsec``.  Every field, and how each is compared: ``docs/regression.md``."""
