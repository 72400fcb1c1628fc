"""The test suite: one folder per package, one file per module."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
"""The checkout the tests run from (tests may read its docs, tools and committed data)."""
DATA = REPO / "tests" / "data"
"""Committed test data: golden image sets."""
