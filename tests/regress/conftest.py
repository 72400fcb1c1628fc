"""Fixtures of the regression tests: a real MicroPython 1.27 unix port built as the flight MCU
runs it (32-bit, single-precision floats in the object word, ``MICROPY_OBJ_REPR_C``, the MCU
image frozen by the repository's ``manifest.py``;
:func:`lodestar.regress.unixport.float32_build`), and the same MicroPython in the STM32
port's default object representation, nothing frozen, for the time calibration
(:func:`lodestar.regress.unixport.reference_build`).

Needs MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD``, else
``../shared/micropython/build.sh`` beside the checkout) and a C toolchain that can target
``-m32`` (Debian ``gcc-multilib``): tests that use a build skip with the reason otherwise,
and fail instead under ``LODESTAR_REQUIRE_MICROPYTHON`` (CI).  The flight interpreter is
built once into the cache folder and rebuilt incrementally; the reference one is built once
(about 30 s) and reused."""

import os

import pytest

from lodestar.regress import replay, unixport
from tests import REPO


def _buildable():
    """Skip (fail under ``LODESTAR_REQUIRE_MICROPYTHON``) when the builds cannot be made."""
    reason = unixport.unavailable_reason(REPO)
    if reason is not None:
        if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON"):
            pytest.fail(reason)
        pytest.skip(reason)


@pytest.fixture(scope="session")
def float32_frozen():
    _buildable()
    return unixport.float32_build(repo=REPO)


@pytest.fixture(scope="session")
def reference():
    _buildable()
    return unixport.reference_build(repo=REPO)


@pytest.fixture(scope="session")
def regression_set():
    manifest = replay.load_set(replay.DEFAULT_SET)
    return manifest, replay.database_files(manifest)
