"""The package layout's rules: no import cycle, no path into the checkout, an MCU-safe root
and contract, firmware that imports only what the MCU image holds, and a docs index that
reaches every page, and a test run that keeps each ``xdist_group`` on one worker."""

import ast
import importlib
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import lodestar
from lodestar.regress.micropython import IMAGE_REGRESS
from tests import REPO

PACKAGES = ("lodestar", "lodestar.contract", "lodestar.cli", "lodestar.cosim", "lodestar.fly",
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


SCRIPT_FOLDERS = ("tests", "benchmarks", "cocotb_tests")
ABBREVIATIONS = {"lodestar.contract": "C", "lodestar.firmware.status": "S",
                 "lodestar.firmware.geometry": "G", "lodestar.firmware.quaternion": "Q",
                 "numpy": "np", "matplotlib.pyplot": "plt", "hypothesis.strategies": "st",
                 "astropy.units": "u"}
"""The documented module abbreviations (``docs/conventions.md``, Import names); every other
module is imported under its own name, with a leading underscore where a parameter or local of
the importing module takes that name."""
MAX_FUNCTION_LINES = 100


def _sources():
    """``{label: path}`` of the packages' modules and the test and benchmark scripts."""
    out = {name: path for name, path in MODULES.items()}
    for folder in SCRIPT_FOLDERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            out[str(path.relative_to(REPO))] = path
    return out


SOURCES = _sources()


def _is_project_module(name):
    if name in MODULES:
        return True
    parts = name.split(".")
    return parts[0] in SCRIPT_FOLDERS and (REPO.joinpath(*parts).with_suffix(".py").is_file()
                                           or REPO.joinpath(*parts, "__init__.py").is_file())


def _module_aliases(label, path):
    """``(module, alias)`` of every ``import M as A`` / ``from P import M as A`` in a source."""
    package = label if path.name == "__init__.py" else label.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, a.asname) for a in node.names if a.asname]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            out += [(base + "." + a.name, a.asname) for a in node.names if a.asname]
    return out


@pytest.mark.parametrize("label", sorted(SOURCES))
def test_modules_are_imported_under_their_own_names(label):
    """An alias names a module only by its documented abbreviation: a reader who greps for
    the name at a call site finds the module."""
    for module, alias in _module_aliases(label, SOURCES[label]):
        if module in ABBREVIATIONS:
            assert alias == ABBREVIATIONS[module], (module, alias)
        elif _is_project_module(module):
            assert alias.lstrip("_") == module.rpartition(".")[2], (module, alias)


def _functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_function_over_100_lines(name):
    tree = ast.parse(MODULES[name].read_text())
    long = [(f.name, f.lineno, f.end_lineno - f.lineno + 1) for f in _functions(tree)
            if f.end_lineno - f.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, long


@pytest.mark.parametrize("name", sorted(m for m in MODULES if m.startswith("lodestar.hdl.")))
def test_gateware_neither_branches_on_sensor_names_nor_passes_bags(name):
    """Sensors are rows of the front-end table, and stages have declared interfaces: no
    ``sensor == "mt9p031"`` and no ``SimpleNamespace`` in ``hdl/``."""
    from lodestar.contract import SENSORS
    tree = ast.parse(MODULES[name].read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            constants = [n.value for n in [node.left, *node.comparators]
                         if isinstance(n, ast.Constant)]
            assert not set(constants) & set(SENSORS), (name, node.lineno)
        if isinstance(node, ast.Name):
            assert node.id != "SimpleNamespace", (name, node.lineno)
        if isinstance(node, ast.alias):
            assert node.name != "SimpleNamespace", name


def _linked_files(page):
    """Files the Markdown links of ``page`` point to (resolved, anchors dropped)."""
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text())
    return {(page.parent / t).resolve() for t in targets if "://" not in t}


def test_docs_index_links_every_page():
    """``docs/README.md`` links every page of ``docs/`` and the README links it: every page
    is reachable from the README."""
    docs = REPO / "docs"
    index = docs / "README.md"
    linked = _linked_files(index)
    pages = {p.resolve() for p in docs.glob("*.md")} - {index.resolve()}
    assert sorted(p.name for p in pages - linked) == []
    assert all(p.exists() for p in linked), sorted(str(p) for p in linked if not p.exists())
    assert index.resolve() in _linked_files(REPO / "README.md")


def test_xdist_groups_keep_to_one_worker(tmp_path):
    """The README's ``pytest -n 2`` runs with ``--dist loadgroup`` (pyproject): the tests of
    an ``xdist_group`` (one Verilated build, one QEMU image, one set of simulated frames)
    must run on one worker.  pytest 9.2 with pytest-xdist 3.8 silently spreads them
    (pytest-xdist#1386), so two workers build the same thing or wait on each other's lock;
    pyproject pins pytest below 9.2."""
    (tmp_path / "test_grouped.py").write_text(
        "import os, pytest\n"
        "pytestmark = pytest.mark.xdist_group('g')\n"
        "@pytest.mark.parametrize('i', range(8))\n"
        "def test_a(i):\n"
        "    with open('workers.txt', 'a') as f:\n"
        "        f.write(os.environ['PYTEST_XDIST_WORKER'] + '\\n')\n")
    run = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup",
                          "-q", "-p", "no:cacheprovider", "test_grouped.py"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    workers = (tmp_path / "workers.txt").read_text().split()
    assert len(workers) == 8 and len(set(workers)) == 1, workers
