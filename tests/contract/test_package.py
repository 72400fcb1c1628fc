"""lodestar.contract (the package): its names resolved from the submodules on first use."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from lodestar import contract as C
from lodestar.contract import detection, integers, link, packet


def test_every_public_name_of_the_four_submodules_reads_through_the_package():
    for module in (detection, integers, link, packet):
        for name in dir(module):
            if not name.startswith("_") and not isinstance(getattr(module, name),
                                                           type(sys)):
                assert getattr(C, name) is getattr(module, name), name


def test_from_import_gives_names_and_submodules():
    from lodestar.contract import REGISTER_BY_NAME, crc32, stardb, telemetry
    assert REGISTER_BY_NAME is detection.REGISTER_BY_NAME and crc32 is packet.crc32
    assert stardb is importlib.import_module("lodestar.contract.stardb")
    assert telemetry is importlib.import_module("lodestar.contract.telemetry")


def test_an_unknown_name_raises_attribute_error():
    for name in ("NO_SUCH_NAME", "_private"):
        assert not hasattr(C, name)
    with pytest.raises(ImportError):
        exec("from lodestar.contract import NO_SUCH_NAME", {})


def test_the_package_keeps_only_the_names_read():
    """A fresh interpreter: the package's dictionary holds a name once it is read, not the
    submodules' 138 names (heap on the MCU: ``docs/mcu_board.md``, Heap and stack)."""
    code = ("import lodestar.contract.packet as P, lodestar.contract as C\n"
            "before = set(vars(C))\n"
            "C.MAX_WIDTH\n"
            "print(len(before), 'MAX_WIDTH' in before, sorted(set(vars(C)) - before))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split(None, 2)
    assert int(out[0]) < 20 and out[1] == "False" and out[2].strip() == "['MAX_WIDTH']"


def test_every_submodule_is_listed():
    """MicroPython imports a submodule through the package's ``__getattr__`` only when it is
    in ``_MODULES`` (else ``from lodestar.contract import it`` fails before its first
    import)."""
    here = Path(C.__file__).parent
    assert set(C._MODULES) == {p.stem for p in here.glob("*.py")} - {"__init__"}
