"""The architecture as docs/architecture.md draws it: imports point one way.

The import graph is read from the source (every import, also inside functions; names imported
only for type checking are left out, since they never run). The rules:

- no import circle among the modules of fleet/ and plugins/;
- the core never imports the built-in plugins (they register through entry points, as a third
  party's do);
- each room imports only the rooms below it (`MAY_IMPORT`, the table in docs/architecture.md);
- every package says its one job in its ``__init__`` docstring;
- no class spans more than `MAX_CLASS_LINES` lines, and `fleet/engine/world.py` (the SimPy loop
  and the wiring) stays under 500 lines;
- fleet/ keeps only cli, errors and highs beside its rooms;
- every package on disk is listed in pyproject, and every data file inside one is package data.
"""

from __future__ import annotations

import ast
import fnmatch
import tomllib
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Room -> the rooms (besides itself) its modules may import. A room is a module or package of
#: fleet/; the longest matching name counts. Keep in step with docs/architecture.md.
MAY_IMPORT: dict[str, set[str]] = {
    "fleet.errors": set(),
    "fleet.highs": {"fleet.errors"},
    "fleet.floor": {"fleet.errors"},
    "fleet.printing": {"fleet.errors", "fleet.floor"},
    "fleet.paths": {"fleet.errors", "fleet.floor", "fleet.highs"},
    "fleet.scenario": {"fleet.errors", "fleet.printing"},
    "fleet.plugins": {"fleet.errors"},
    "fleet.bus": {"fleet.errors", "fleet.plugins"},
    "fleet.plugins.testing": {
        "fleet.errors", "fleet.floor", "fleet.paths", "fleet.plugins", "fleet.bus",
    },
    "fleet.engine": {
        "fleet.errors", "fleet.floor", "fleet.paths", "fleet.printing", "fleet.scenario",
        "fleet.plugins", "fleet.bus",
    },
    "fleet.view": {"fleet.errors", "fleet.floor"},
    "fleet.study": {
        "fleet.errors", "fleet.floor", "fleet.highs", "fleet.printing", "fleet.scenario",
        "fleet.plugins", "fleet.engine", "fleet.view",
    },
    "fleet.api": {
        "fleet.errors", "fleet.scenario", "fleet.engine", "fleet.study", "fleet.view",
    },
}  # fmt: skip

#: Rooms that may import any room: the command line and `python -m fleet`.
TOP = {"fleet.cli", "fleet.__main__"}

#: Most lines a class may span, from its `class` line to its last: more is more than one job.
MAX_CLASS_LINES = 400


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == "plugins":
        parts[0] = "fleet_plugins"
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in [*ROOT.glob("fleet/**/*.py"), *ROOT.glob("plugins/**/*.py")]}


class _Imports(ast.NodeVisitor):
    """The modules of the project that one module imports at run time."""

    def __init__(self, module: str, is_package: bool) -> None:
        self.module = module
        self.package = module if is_package else module.rpartition(".")[0]
        self.found: set[str] = set()

    def visit_If(self, node: ast.If) -> None:
        if "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._add(alias.name)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level:
            base = self.package.rsplit(".", node.level - 1)[0] if node.level > 1 else self.package
            source = f"{base}.{node.module}" if node.module else base
        else:
            source = node.module or ""
        for alias in node.names:
            submodule = f"{source}.{alias.name}"
            self._add(submodule if submodule in MODULES else source)

    def _add(self, name: str) -> None:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        if name and name != self.module:
            self.found.add(name)


def import_graph() -> nx.DiGraph:
    graph = nx.DiGraph()
    for module, path in MODULES.items():
        graph.add_node(module)
        visitor = _Imports(module, path.name == "__init__.py")
        visitor.visit(ast.parse(path.read_text(encoding="utf-8")))
        graph.add_edges_from((module, target) for target in visitor.found)
    return graph


def room_of(module: str) -> str | None:
    rooms = [r for r in [*MAY_IMPORT, *TOP] if module == r or module.startswith(r + ".")]
    return max(rooms, key=len) if rooms else None


def test_there_is_no_import_circle():
    assert list(nx.simple_cycles(import_graph())) == []


def test_the_core_never_imports_the_built_in_plugins():
    graph = import_graph()
    wrong = [
        (a, b) for a, b in graph.edges if a.startswith("fleet.") and b.startswith("fleet_plugins")
    ]
    assert wrong == []


def test_every_module_of_the_core_has_a_room():
    assert [m for m in MODULES if m.startswith("fleet.") and room_of(m) is None] == []


def test_each_room_imports_only_the_rooms_below_it():
    wrong = []
    for a, b in import_graph().edges:
        here, there = room_of(a), room_of(b)
        if here is None or there is None or here == there or here in TOP:
            continue
        if there not in MAY_IMPORT[here]:
            wrong.append(f"{a} -> {b}")
    assert wrong == []


def test_the_rules_are_themselves_one_way():
    rooms = nx.DiGraph((a, b) for a, allowed in MAY_IMPORT.items() for b in allowed)
    assert list(nx.simple_cycles(rooms)) == []


@pytest.mark.parametrize(
    "package", sorted(m for m, p in MODULES.items() if p.name == "__init__.py")
)
def test_every_package_says_its_job(package):
    docstring = ast.get_docstring(ast.parse(MODULES[package].read_text(encoding="utf-8")))
    assert docstring and len(docstring.split()) >= 5, package


def test_the_core_keeps_at_most_three_modules_beside_its_rooms():
    loose = sorted(
        p.name
        for p in (ROOT / "fleet").glob("*.py")
        if p.name not in {"__init__.py", "__main__.py"}
    )
    assert loose == ["cli.py", "errors.py", "highs.py"]


def classes_over(limit: int, modules: dict[str, Path]) -> list[str]:
    """``module.Class (n lines)`` for every class in `modules`, nested ones too, over `limit`."""
    over = []
    for module, path in sorted(modules.items()):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > limit:
                    over.append(f"{module}.{node.name} ({lines} lines)")
    return over


def test_no_class_is_over_400_lines():
    assert classes_over(MAX_CLASS_LINES, MODULES) == []


#: Every new feature tempts to land in the World, so its size is watched.
WORLD_MAX_LINES = 500


def test_the_world_is_the_loop_and_the_wiring_in_under_500_lines():
    lines = len((ROOT / "fleet" / "engine" / "world.py").read_text(encoding="utf-8").splitlines())
    assert lines < WORLD_MAX_LINES, (
        f"fleet/engine/world.py has {lines} lines: give the new job a collaborator of its own"
    )


def test_every_package_on_disk_is_one_the_distribution_ships():
    # An editable install finds any folder; a wheel ships only the packages pyproject lists.
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    on_disk = {m for m, p in MODULES.items() if p.name == "__init__.py"}
    assert listed == on_disk


def test_every_data_file_in_a_package_ships_with_it():
    # A wheel carries only the files package-data names: a page template left out would be
    # missed by no test run from the source tree, only by users.
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {name: ROOT / path for name, path in setuptools["package-dir"].items()}
    data = setuptools.get("package-data", {})
    missing = []
    for package in setuptools["packages"]:
        top, *rest = package.split(".")
        folder = folders[top].joinpath(*rest)
        for path in folder.rglob("*"):
            inner = path.relative_to(folder)
            if not path.is_file() or path.suffix in {".py", ".pyc"} or "__pycache__" in inner.parts:
                continue
            owned = any(
                (folder / sub).is_dir() and (folder / sub / "__init__.py").is_file()
                for sub in [Path(*inner.parts[:i]) for i in range(1, len(inner.parts))]
            )
            if owned:
                continue  # a subpackage's file: judged with that package
            if not any(fnmatch.fnmatch(inner.as_posix(), g) for g in data.get(package, [])):
                missing.append(f"{package}: {inner.as_posix()}")
    assert not missing, f"not in [tool.setuptools.package-data]: {missing}"
