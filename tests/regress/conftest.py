"""Fixtures of the regression tests: a real MicroPython 1.27 unix port built as the flight MCU
runs it (32-bit where the C compiler can target -m32, single-precision floats, the MCU image
frozen by the repository's ``manifest.py``; :func:`lodestar.regress.unixport.float32_build`).

Needs MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD``, else
``../shared/micropython/build.sh`` beside the checkout) and a C toolchain: tests that use
the build skip with the reason otherwise, and fail instead under
``LODESTAR_REQUIRE_MICROPYTHON`` (CI).  The interpreter is built once into the cache folder
and rebuilt incrementally."""

import os

import pytest

from lodestar.regress import replay as regress
from lodestar.regress import unixport
from tests import REPO


@pytest.fixture(scope="session")
def float32_frozen():
    reason = unixport.unavailable_reason(REPO)
    if reason is not None:
        if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON"):
            pytest.fail(reason)
        pytest.skip(reason)
    return unixport.float32_build(repo=REPO)


@pytest.fixture(scope="session")
def regression_set():
    manifest = regress.load_set(regress.DEFAULT_SET)
    return manifest, regress.database_files(manifest)
