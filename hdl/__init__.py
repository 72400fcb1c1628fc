"""Amaranth gateware of the detection pipeline; its executable spec is
``lodestar.golden.streaming`` and every width and layout comes from ``lodestar.contract``."""
