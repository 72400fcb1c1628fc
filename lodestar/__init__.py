"""lodestar: star-detection gateware and flight software of a nanosatellite star tracker.

This root and :mod:`lodestar.contract` are MicroPython-safe: the MCU image holds them with
:mod:`lodestar.firmware`.  The README's layout table gives the packages in data-flow order.
"""
