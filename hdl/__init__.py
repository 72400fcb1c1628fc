"""Amaranth gateware of the detection pipeline.  Every width and layout comes from
``lodestar.contract``; the labeller's executable spec is ``golden/wavefront.py``."""
