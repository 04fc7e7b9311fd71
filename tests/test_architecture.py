"""The layers of docs/ARCHITECTURE.md, checked on the source: every import statement (module level
and inside functions) of the three top-level packages is read with ``ast`` and must go in an
allowed direction; neither the module graph nor the package graph may have a cycle.

    core  <-  domain packages (never sideways)  <-  app  <-  bench  <-  commands (+ cli)

A new domain package (e.g. ``spinemocap.bodymodel``, ``spinemocap.opensim``) only needs an entry in
``UNITS`` (it then may import core only); a new core module goes into ``CORE``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from repo_paths import ROOT

PACKAGES = ("spinemocap", "calibration", "exporters")

# core: small modules of shared types and helpers; they import only each other
CORE = {f"spinemocap.{name}" for name in
        ("version", "camera", "tape", "markers", "capture", "media", "timebase", "views", "geometry", "fileio", "timing",
         "skin", "reference", "frames", "rig_adjust", "anatomy")}
# unit (module prefix) -> layer
UNITS = {
    "spinemocap.detect": "domain",
    "spinemocap.track": "domain",
    "spinemocap.synth": "domain",
    "spinemocap.analysis": "domain",
    "spinemocap.bodymodel": "domain",
    "spinemocap.crossval": "domain",
    "spinemocap.opensim": "domain",
    "calibration": "domain",
    "exporters": "domain",
    "spinemocap.app": "app",
    "spinemocap.bench": "bench",
    "spinemocap.commands": "commands",
    "spinemocap.cli": "commands",
    "spinemocap.__main__": "commands",
}
# the layers, bottom up: a unit imports its own unit or a lower layer (domain: core only)
ORDER = ("core", "domain", "app", "bench", "commands")
# the package root re-exports the public API lazily: it may name anything, nobody imports it
API = "spinemocap"


def unit_of(module: str) -> str:
    if module == API:
        return API
    if module in CORE:
        return "core"
    for prefix in sorted(UNITS, key=len, reverse=True):
        if module == prefix or module.startswith(prefix + "."):
            return prefix
    raise AssertionError(f"{module} is in no layer: add it to CORE or UNITS in tests/test_architecture.py")


def layer_of(unit: str) -> str:
    return {API: "api", "core": "core"}.get(unit) or UNITS[unit]


def allowed(src_unit: str, dst_unit: str) -> bool:
    """May code in ``src_unit`` import ``dst_unit``?"""
    if src_unit == dst_unit:
        return True
    src, dst = layer_of(src_unit), layer_of(dst_unit)
    if dst == "api":
        return False  # import the defining module instead
    if src == "api":
        return True
    if src == "domain":
        return dst == "core"  # domain packages never import each other
    if src == dst:
        return src != "domain"  # the application layers are one unit each, core modules import each other
    return ORDER.index(dst) < ORDER.index(src)


def module_files() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = module_files()


def imports_of(module: str, path: Path) -> list[tuple[str, int]]:
    """(imported module of ours, line) for every import statement in the file, at any depth."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:  # ``from pkg import submodule`` imports the submodule
                sub = f"{target}.{alias.name}"
                found.append((sub if sub in MODULES else target, node.lineno))
    ours = []
    for name, line in found:
        if name.split(".")[0] not in PACKAGES:
            continue
        while name not in MODULES and "." in name:  # ``import a.b.c`` of a name inside a module
            name = name.rpartition(".")[0]
        ours.append((name, line))
    return ours


GRAPH = {module: imports_of(module, path) for module, path in MODULES.items()}


def test_every_module_has_a_layer():
    for module in MODULES:
        unit_of(module)


def test_imports_follow_the_layers():
    wrong = []
    for module, imports in GRAPH.items():
        for target, line in imports:
            src, dst = unit_of(module), unit_of(target)
            if not allowed(src, dst):
                wrong.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {module} ({layer_of(src)}) "
                             f"imports {target} ({layer_of(dst)})")
    assert not wrong, "imports against the layers (docs/ARCHITECTURE.md):\n" + "\n".join(wrong)


def cycles_of(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one node."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w == v:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return cycles


def test_no_import_cycles():
    """Over the module graph (function-level imports too)."""
    cycles = cycles_of({module: {target for target, _ in imports} for module, imports in GRAPH.items()})
    assert not cycles, f"import cycles: {cycles}"


def test_no_package_cycles():
    """Over the graph of units (the packages of :data:`UNITS`, subpackages included, and core): a
    module of unit A importing one of B and a module of B importing one of A is a cycle even when
    the two modules' own graph has none."""
    packages: dict[str, set[str]] = {}
    for module, imports in GRAPH.items():
        edges = packages.setdefault(unit_of(module), set())
        edges |= {unit_of(target) for target, _ in imports} - {unit_of(module)}
    for package in list(packages.values()):
        for target in package:
            packages.setdefault(target, set())
    cycles = cycles_of(packages)
    assert not cycles, f"package import cycles: {cycles}"


@pytest.mark.parametrize("src,dst,ok", [
    ("spinemocap.detect", "core", True),
    ("spinemocap.detect", "spinemocap.track", False),
    ("calibration", "exporters", False),
    ("spinemocap.bodymodel", "spinemocap.synth", False),
    ("core", "spinemocap.track", False),
    ("spinemocap.app", "spinemocap.track", True),
    ("spinemocap.app", "spinemocap.bench", False),
    ("spinemocap.app", "spinemocap.commands", False),
    ("spinemocap.bench", "spinemocap.app", True),
    ("spinemocap.bench", "spinemocap.commands", False),
    ("spinemocap.bench", "spinemocap.cli", False),
    ("spinemocap.commands", "spinemocap.bench", True),
    ("spinemocap.commands", "spinemocap.app", True),
    ("spinemocap.cli", "spinemocap.commands", True),
    ("exporters", "core", True),
    ("exporters", "spinemocap.app", False),
    ("calibration", "spinemocap.bench", False),
    ("spinemocap.track", API, False),
])
def test_the_rules_themselves(src, dst, ok):
    assert allowed(src, dst) is ok


def test_the_checker_sees_function_level_imports(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("def f():\n    from ..track.pipeline import FrameTracker\n")
    assert imports_of("spinemocap.detect.probe", path) == [("spinemocap.track.pipeline", 2)]


def package_folders() -> set[str]:
    """Folders of the packages relative to the ``spinemocap`` package root (``calibration`` and
    ``exporters`` sit beside it and count as top-level folders)."""
    folders = {str(p.parent.relative_to(ROOT / "spinemocap")) for p in (ROOT / "spinemocap").rglob("*.py")}
    return (folders - {"."}) | {"calibration", "exporters"}


def test_tests_mirror_the_package_tree():
    """Every test file sits in the folder of the package it exercises (core modules' tests at the top)."""
    helper_folders = {"export_plugin"}
    test_folders = {str(p.parent.relative_to(ROOT / "tests")) for p in (ROOT / "tests").rglob("test_*.py")}
    strays = sorted(test_folders - {"."} - package_folders() - helper_folders)
    assert not strays, f"test folders that mirror no package: {strays}"


def _reexports() -> dict[tuple[str, str], str]:
    """(package, name) -> the submodule of that package a package's ``__init__`` imports the name from."""
    out = {}
    for module, path in MODULES.items():
        if path.name != "__init__.py":
            continue
        for node in ast.parse(path.read_text(), str(path)).body:
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                for alias in node.names:
                    out[(module, alias.asname or alias.name)] = f"{module}.{node.module}"
    return out


def test_mirrored_test_folder():
    assert mirrored_test_folder("spinemocap.track.lp") == ROOT / "tests" / "track"
    assert mirrored_test_folder("spinemocap.app.viewer.video") == ROOT / "tests" / "app" / "viewer"
    assert mirrored_test_folder("spinemocap.geometry") == ROOT / "tests"
    assert mirrored_test_folder("calibration.formats.vicon") == ROOT / "tests" / "calibration"


def mirrored_test_folder(module: str) -> Path:
    """Where the tests of ``module`` sit: ``tests/<its folder under spinemocap/>``; a core module's
    at the top of ``tests/``; every module of ``calibration`` / ``exporters`` in ``tests/calibration`` /
    ``tests/exporters``."""
    path = MODULES[module].relative_to(ROOT)
    if path.parts[0] != "spinemocap":
        return ROOT / "tests" / path.parts[0]
    return ROOT / "tests" / Path(*path.parts[1:-1])


# run as a program (tests/test_package_main.py runs it), or a folder of data (the shipped weights)
NOT_IMPORTED = {"spinemocap.__main__", "spinemocap.detect.weights"}


def test_every_module_is_exercised_by_a_test_of_its_folder():
    """Each module is imported (directly, or by the name its package re-exports from it) by a
    ``test_*.py`` in the folder that mirrors its own."""
    reexports = _reexports()
    imported: dict[Path, set[str]] = {}
    for test in (ROOT / "tests").rglob("test_*.py"):
        names = set()
        for node in ast.walk(ast.parse(test.read_text(), str(test))):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names |= {reexports.get((node.module, alias.name), f"{node.module}.{alias.name}") for alias in node.names}
                names.add(node.module)
            elif isinstance(node, ast.Import):
                names |= {alias.name for alias in node.names}
        parents = {name.rsplit(".", k)[0] for name in names for k in range(1, name.count(".") + 1)}
        imported.setdefault(test.parent, set()).update(names | parents)  # a package: through its modules
    untested = sorted(module for module in MODULES if module not in NOT_IMPORTED and module != API
                      and module not in imported.get(mirrored_test_folder(module), set()))
    assert not untested, f"modules no test of their mirrored folder imports: {untested}"


def test_test_file_names_are_unique():
    """pytest imports each test file by its name alone (the test folders are no packages): two files
    of one name in different folders stop the collection."""
    names = [path.name for path in (ROOT / "tests").rglob("test_*.py")]
    assert not {name for name in names if names.count(name) > 1}
