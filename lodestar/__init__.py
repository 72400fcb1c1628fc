"""lodestar: star-detection gateware and flight software of a nanosatellite star tracker.

Data flow and packages:
``lodestar.contract`` (limits, widths, registers, record and packet layout; pure Python)
-> ``lodestar.golden`` (bit-exact reference detector) and ``lodestar.hdl`` (Amaranth gateware)
-> ``lodestar.packet`` (FPGA->MCU packets) -> ``lodestar.firmware`` (MCU code).
"""
