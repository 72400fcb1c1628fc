"""lodestar: star-detection gateware and flight software of a nanosatellite star tracker.

Data flow and packages:
``lodestar.contract`` (limits, widths, registers, record and packet layout; pure Python)
-> ``lodestar.golden`` (bit-exact reference detector) and ``lodestar.hdl`` (Amaranth gateware)
-> ``lodestar.packet`` (FPGA->MCU packets) -> ``lodestar.firmware`` (MCU code).
"""


def solve_centroids(*args, **kwargs):
    """Ground-side star-field solve from centroids (tetra3 style); see
    ``lodestar.solve.solve_centroids``.  Imported on first use so that this package stays
    loadable on the MCU, where numpy does not exist."""
    from lodestar.solve import solve_centroids as solve

    return solve(*args, **kwargs)
