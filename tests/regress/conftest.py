"""Fixtures of the regression tests: a real MicroPython 1.27 unix port built as the flight MCU
runs it (32-bit where the C compiler can target -m32, single-precision floats, the MCU image
frozen by the repository's ``manifest.py``).

Needs MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD``, else
``../shared/micropython/build.sh`` beside the checkout) and a C toolchain: tests that use
the build skip with the reason otherwise, and fail instead under
``LODESTAR_REQUIRE_MICROPYTHON`` (CI).  The interpreter is built once into the cache folder
and rebuilt incrementally."""

import os
import shutil

import pytest

from lodestar.ground.cache import default_cache_dir
from lodestar.regress import replay as regress
from lodestar.regress import unixport
from tests import REPO


def _build_script():
    script = unixport.build_script(REPO)
    reason = None
    if script is None:
        reason = (f"no MicroPython build script (set {unixport.BUILD_ENV} or put "
                  "../shared/micropython beside the checkout)")
    for tool in ("make", "cc", "patch", "tar"):
        if reason is None and shutil.which(tool) is None:
            reason = f"{tool} is not installed (needed to build MicroPython)"
    if reason is not None:
        if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON"):
            pytest.fail(reason)
        pytest.skip(reason)
    return script


@pytest.fixture(scope="session")
def float32_frozen():
    return unixport.build(_build_script(), REPO / "manifest.py",
                          default_cache_dir() / "micropython", "float32")


@pytest.fixture(scope="session")
def regression_set():
    manifest = regress.load_set(regress.DEFAULT_SET)
    return manifest, regress.database_files(manifest)
