"""The package layout's rules: no import cycle, no path into the checkout, an MCU-safe root
and contract, and firmware that imports only what the MCU image holds."""

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

import lodestar
from lodestar.regress.micropython import IMAGE_REGRESS

PACKAGES = ("lodestar", "lodestar.contract", "lodestar.cli", "lodestar.cosim",
            "lodestar.regress", "lodestar.golden", "lodestar.hdl", "lodestar.firmware",
            "lodestar.sim", "lodestar.ground", "lodestar.ground.campaign")
MCU_PACKAGES = ("lodestar.contract", "lodestar.firmware")
"""What the MCU image holds besides the root (``lodestar.regress.micropython.mcu_image``)."""


MCU_REGRESS = ("lodestar.regress", "lodestar.regress.mcu", "lodestar.regress.loop")
"""The MCU side of the regression, also in the image
(``lodestar.regress.micropython.IMAGE_REGRESS``)."""


def on_mcu(name):
    """True for a module of the MCU image."""
    return (name == "lodestar" or name in MCU_REGRESS
            or name in MCU_PACKAGES or name.startswith(tuple(p + "." for p in MCU_PACKAGES)))


MCU_STDLIB = {"math", "struct", "array", "binascii", "gc", "micropython", "sys"}
REGRESS_STDLIB = MCU_STDLIB | {"json", "time"}
"""The regression loop also reads its runs as JSON and times solves (MicroPython's own
``json`` and ``time``)."""


def _modules():
    """``{module name: source path}`` of every module of the installed packages."""
    out = {}
    for name in PACKAGES:
        package = importlib.import_module(name)
        out[name] = Path(package.__file__)
        for info in pkgutil.iter_modules(package.__path__):
            path = Path(package.__path__[0]) / (info.name + ".py")
            if path.is_file():
                out[name + "." + info.name] = path
    return out


MODULES = _modules()


def _imports(name, path):
    """Modules ``name`` imports (absolute names, relative ones resolved)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            found.add(base)
            found.update(base + "." + alias.name for alias in node.names)
    return {m for m in found if m in MODULES}


def test_no_import_cycle():
    graph = {name: _imports(name, path) - {name} for name, path in MODULES.items()}
    # a package's __init__ may re-export its own modules; that is not a cycle
    for name in list(graph):
        graph[name] = {m for m in graph[name] if not name.startswith(m + ".")}
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                pytest.fail("import cycle: " + " -> ".join(stack[stack.index(nxt):] + [nxt]))
            if nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = "done"

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_path_into_the_checkout(name):
    """Runtime code finds data through package resources or arguments, never through the
    source tree (a wheel install has no ``tests/`` or ``tools/``)."""
    source = MODULES[name].read_text()
    assert "parents[" not in source and "parent.parent" not in source


@pytest.mark.parametrize("name", sorted(m for m in MODULES if on_mcu(m)))
def test_mcu_modules_import_only_the_mcu_image(name):
    for module in _imports(name, MODULES[name]):
        assert on_mcu(module), (name, module)
    allowed = REGRESS_STDLIB if name in MCU_REGRESS else MCU_STDLIB
    assert _stdlib_imports(MODULES[name]) <= allowed, name


def test_the_image_is_what_the_rules_check():
    """The image's regression modules are the ones :data:`MCU_REGRESS` holds to its rules."""
    assert {"lodestar.regress" + ("" if m == "__init__" else "." + m) for m in IMAGE_REGRESS} \
        == set(MCU_REGRESS)


def _stdlib_imports(path):
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            if not node.module.startswith("lodestar"):
                out.add(node.module.split(".")[0])
    return out


def test_root_imports_nothing():
    source = Path(lodestar.__file__).read_text()
    assert not [n for n in ast.parse(source).body if isinstance(n, (ast.Import, ast.ImportFrom))]
