"""Firmware regression: recorded FPGA packets replayed through the flight API on CPython
and MicroPython.  :mod:`.mcu` is the replay that runs on the MCU image (MicroPython-safe),
:mod:`.replay` loads a set and compares, :mod:`.record` regenerates it and
:mod:`.micropython` runs MicroPython (the one runner of the command, the tests and the
benchmarks)."""
