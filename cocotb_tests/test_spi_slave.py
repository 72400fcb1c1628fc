"""The SPI slave, Verilated, against a cocotb SPI master model (one build)."""

from simulator import run

from lodestar.hdl.spi_slave import SPISlave


def test_spi_slave_transactions(tmp_path):
    assert run(SPISlave(), "spi_slave", "spi_slave_tb", tmp_path / "build",
               {"TB_SEED": 2024}) == 1
