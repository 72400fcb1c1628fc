"""MCU rules, statically, for every module of the firmware package: imports only from
``math``, ``struct``, ``array``, ``binascii``, ``gc``, ``sys``, ``micropython``, ``lodestar``
or the package itself (no numpy, typing, dataclasses, itertools...), no f-strings."""

import ast
import io
import pathlib
import re
import tokenize

import pytest

from lodestar import firmware

FIRMWARE = pathlib.Path(firmware.__file__).parent
MODULES = sorted(str(p.relative_to(FIRMWARE)) for p in FIRMWARE.rglob("*.py"))


def has_fstring(source):
    """True if ``source`` contains an f-string literal (tokenizer based)."""
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == getattr(tokenize, "FSTRING_START", None):
            return True
        if tok.type == tokenize.STRING:
            prefix = re.match(r"[A-Za-z]*", tok.string).group(0)
            if "f" in prefix.lower():
                return True
    return False


def test_every_module_is_checked():
    assert {"pipeline.py", "geometry.py", "settings.py", "starid/__init__.py",
            "starid/search.py"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_firmware_rules(name):
    source = (FIRMWARE / name).read_text()
    imports = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            imports += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            imports.append(node.module)
    # gc and sys: the pipeline's collector policy on MicroPython; micropython: const()
    # (docs/firmware.md, Memory)
    assert {m.split(".")[0] for m in imports} <= {"math", "struct", "array", "binascii",
                                                   "gc", "sys", "micropython",
                                                   "lodestar"}, imports
    assert not has_fstring(source), "f-strings are avoided in firmware"
