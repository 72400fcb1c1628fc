"""The regression set on a real MicroPython 1.27: the unix port built 32-bit (when the C
compiler can target -m32) with single-precision floats, as the STM32F401 runs it, and the
MCU image frozen into it by the repository's ``manifest.py`` with upstream ``mpy-tool``.

Needs MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD``, else
``../shared/micropython/build.sh`` beside the checkout) and a C toolchain; skipped with the
reason otherwise.  The interpreter is built once into the cache folder and rebuilt
incrementally."""

import os
import shutil
from pathlib import Path

import pytest

from lodestar.ground.cache import default_cache_dir
from lodestar.regress import micropython as mp
from lodestar.regress import replay as regress
from tests import REPO

FLOAT32_ARCSEC = 2.0
"""Largest rotation between a float32 attitude and the recorded double one (measured: 1.09
arcsec, the roll of a lohmann frame)."""


def _build_script():
    path = Path(os.environ.get(mp.BUILD_ENV) or REPO.parent / "shared" / "micropython" /
                "build.sh")
    if not path.is_file():
        pytest.skip(f"no MicroPython build script at {path} (set {mp.BUILD_ENV})")
    for tool in ("make", "cc", "patch", "tar"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (needed to build MicroPython)")
    return path


@pytest.fixture(scope="module")
def float32_frozen():
    return mp.build_unix(_build_script(), REPO / "manifest.py",
                         default_cache_dir() / "micropython", "float32")


def test_the_set_replays_on_float32_micropython_with_the_firmware_frozen(float32_frozen):
    """Every case and method: the status and the identified stars of the recorded (double
    precision) result, the attitude within :data:`FLOAT32_ARCSEC`."""
    manifest = regress.load_set(regress.DEFAULT_SET)
    results = mp.replay_unix(float32_frozen, manifest, regress.DEFAULT_SET,
                             regress.database_files(manifest), manifest["methods"])
    assert len(results) == len(manifest["cases"]) * len(manifest["methods"])
    worst = 0.0
    for case in manifest["cases"]:
        for method in manifest["methods"]:
            got, want = results[(case["name"], method)], case["expected"][method]
            assert (got["status"], got["matches"]) == (want["status"], want["matches"]), \
                (case["name"], method)
            if want["q"] is not None:
                worst = max(worst, regress.rotation_angle(got["q"], want["q"]))
    assert worst * 206264.806 < FLOAT32_ARCSEC


def test_the_frozen_image_is_the_mcu_image(tmp_path):
    """The staged tree holds exactly the MCU image: the root, the contract and the
    firmware, nothing of the ground."""
    staged = mp.stage_mcu_image(tmp_path)
    files = sorted(str(p.relative_to(staged)) for p in staged.rglob("*.py"))
    assert "lodestar/__init__.py" in files and "lodestar/firmware/pipeline.py" in files
    assert "lodestar/contract/packet.py" in files
    assert all(f.startswith(("lodestar/firmware/", "lodestar/contract/")) or
               f == "lodestar/__init__.py" for f in files)
