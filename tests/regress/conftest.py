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
(about 30 s) and reused.  The Cortex-M4F build (:mod:`lodestar.regress.qemu`) needs
``build-qemu.sh`` beside the build script, ``arm-none-eabi-gcc`` with newlib and
``qemu-system-arm``, and skips or fails the same way; the whole set runs on it once per
session."""

import os

import pytest

from lodestar.regress import qemu, replay, unixport
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


def _qemu_buildable():
    reason = qemu.unavailable_reason(REPO)
    if reason is not None:
        if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON"):
            pytest.fail(reason)
        pytest.skip(reason)


@pytest.fixture(scope="session")
def cortex_m4f(regression_set):
    """The Cortex-M4F image of the set's expectations (:data:`~lodestar.regress.qemu.
    EXPECTATION_HEAP` of heap, the set frozen, :func:`lodestar.regress.qemu.
    expectation_build`): the flight image but for a larger heap, so one build serves the
    session (the flight heap is this one less a ballast); skips, or fails under
    ``LODESTAR_REQUIRE_MICROPYTHON``, without the ARM toolchain and QEMU."""
    _qemu_buildable()
    manifest, db_files = regression_set
    return qemu.expectation_build(manifest, replay.DEFAULT_SET, db_files, repo=REPO)


@pytest.fixture(scope="session")
def cortex_m4f_set(cortex_m4f, regression_set):
    """The whole set, every method, in one QEMU run at issue 29's 64 KiB
    (:data:`~lodestar.regress.qemu.SET_HEAP`: the build's heap less a ballast of the
    difference held from the start; a few hundred bytes less than the flight build's own
    pool, whose allocation tables are smaller) with the flight packet buffer
    (:func:`lodestar.regress.qemu.flight_loop`)."""
    manifest, db_files = regression_set
    runs = [(case, method) for method in manifest["methods"] for case in manifest["cases"]]
    return qemu.flight_loop(cortex_m4f, manifest, db_files, runs, heap=qemu.EXPECTATION_HEAP,
                            ballast=qemu.EXPECTATION_HEAP - qemu.SET_HEAP)


@pytest.fixture(scope="session")
def cortex_m4f_outcomes(cortex_m4f, regression_set):
    """The whole set on the build of the expectations in one QEMU run."""
    manifest, db_files = regression_set
    return qemu.float32_outcomes(cortex_m4f, manifest, db_files)
