"""The library's layout as the README's map draws it: every module named, floors respected, no circles.

The map in README.md ("## Layout") lists every module and package of ``pipeline/`` under a ``# floor N`` heading,
from the ground up. A module imports only from its own floor or the floors below it (lazy imports inside functions
count; ``if TYPE_CHECKING:`` blocks do not), no two modules import each other, and no library module exceeds the
line budget. The vocabulary of the feature store (``DOFS``, per-DOF column names) is defined in one module, the
fourth-order Runge-Kutta step in one, and no function outside ``pipeline/models/`` reads a model's private state.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ROOT / "pipeline"
MAX_LINES = 600


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def library_modules() -> dict[str, Path]:
    """Every module of ``pipeline/`` (a package is its ``__init__``), by dotted name."""
    return {module_name(p): p for p in sorted(LIBRARY.rglob("*.py"))}


def readme_map() -> dict[str, int]:
    """``{dotted name: floor}`` of every module and package the README's map names."""
    text = (ROOT / "README.md").read_text()
    block = text.split("## Layout", 1)[1].split("```", 2)[1]
    floors: dict[str, int] = {}
    floor = None
    stack: list[tuple[int, str]] = []  # (indent, dotted name of an open package)
    for line in block.splitlines():
        if not line.strip() or not line.startswith("  "):
            continue
        indent = len(line) - len(line.lstrip())
        entry = line.strip().split()[0]
        heading = re.match(r"#\s*floor\s+(\d+)", line.strip())
        if heading:
            floor, stack = int(heading.group(1)), []
            continue
        if entry.startswith("#") or not re.fullmatch(r"[a-z_0-9]+(\.py|/)", entry):
            continue  # a continuation line of a description
        while stack and stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1] if stack else "pipeline"
        name = f"{parent}.{entry.removesuffix('.py').removesuffix('/')}"
        assert floor is not None, f"README map: {entry} comes before any '# floor N' heading"
        floors[name] = floor
        if entry.endswith("/"):
            stack.append((indent, name))
    return floors


def imports_of(path: Path, name: str, known: set[str]) -> set[str]:
    """The library modules ``path`` imports at run time (lazy ones included, type-checking ones not)."""
    tree = ast.parse(path.read_text())
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for child in node.body for n in ast.walk(child))
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package[: len(package) - node.level + 1]
                base = ".".join([*up, *([node.module] if node.module else [])])
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


MODULES = library_modules()
GRAPH = {name: imports_of(path, name, set(MODULES)) for name, path in MODULES.items()}


def test_the_readme_map_names_every_module_and_nothing_else() -> None:
    named = set(readme_map())
    on_disk = set(MODULES) - {"pipeline"}
    assert sorted(on_disk - named) == [], "modules the README's map does not name"
    assert sorted(named - on_disk) == [], "the README's map names modules that do not exist"


def test_no_module_imports_one_on_a_higher_floor() -> None:
    floors = readme_map() | {"pipeline": 0}
    wrong = [f"{a} (floor {floors[a]}) imports {b} (floor {floors[b]})"
             for a, targets in GRAPH.items() for b in sorted(targets) if floors[b] > floors[a]]
    assert wrong == []


def test_no_two_modules_import_each_other() -> None:
    pairs = sorted({tuple(sorted((a, b))) for a, targets in GRAPH.items() for b in targets if a in GRAPH[b]})
    assert pairs == []


def test_only_the_app_floor_imports_the_stage_shells() -> None:
    floors = readme_map()
    top = max(floors.values())
    wrong = []
    for name, path in MODULES.items():
        if name != "pipeline" and floors.get(name, top) < top and re.search(r"^\s*(from|import) stages\b",
                                                                               path.read_text(), re.M):
            wrong.append(name)
    assert wrong == []


@pytest.mark.parametrize("name", sorted(MODULES))
def test_library_modules_stay_under_the_line_budget(name: str) -> None:
    assert len(MODULES[name].read_text().splitlines()) <= MAX_LINES


def _module_level_assignments(target: str) -> list[str]:
    return [name for name, path in MODULES.items() for node in ast.parse(path.read_text()).body
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == target for t in node.targets)]


@pytest.mark.parametrize("vocabulary", ["DOFS", "VEL_UNIT", "ACC_UNIT", "FORCE_UNITS", "VELOCITY_COLUMNS",
                                        "TAU_COLUMNS", "DAMPING_COLUMNS", "NOISE_STD_COLUMNS"])
def test_the_store_vocabulary_is_defined_once(vocabulary: str) -> None:
    assert _module_level_assignments(vocabulary) == ["pipeline.vocabulary"]


def test_one_runge_kutta_step() -> None:
    """The fourth stage of RK4 (``k4 = f(x + h * k3, ...)``) is written in one module."""
    rk4 = re.compile(r"\bk4\s*=\s*\w+\(")
    assert [name for name, path in MODULES.items() if rk4.search(path.read_text())] == ["pipeline.rk4"]


def _model_state() -> set[str]:
    """Private attributes the classes of pipeline/models/ keep on themselves (``_y_1d``); fitted state that ends in
    ``_`` is public in scikit-learn's convention (``coef_``) and may be read."""
    names = {"_gamma"}  # libsvm's resolved gamma, read by the SVRs' fast path
    for name, path in MODULES.items():
        if name.startswith("pipeline.models"):
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self"
                        and isinstance(node.ctx, ast.Store) and node.attr.startswith("_")
                        and not node.attr.startswith("__")):
                    names.add(node.attr)
    return names


def test_no_function_outside_models_reads_a_models_private_state() -> None:
    """Outside pipeline/models/, no code reads a model's private state (by attribute or by ``getattr``): it calls
    the model's methods instead (``predict``, the fast path)."""
    state = _model_state()
    wrong = []
    for name, path in MODULES.items():
        if name.startswith("pipeline.models"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in state and not (
                    isinstance(node.value, ast.Name) and node.value.id in {"self", "cls"}):
                wrong.append(f"{name}:{node.lineno} .{node.attr}")
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in {"getattr", "hasattr"} and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant) and node.args[1].value in state):
                wrong.append(f"{name}:{node.lineno} {node.func.id}(..., {node.args[1].value!r})")
    assert wrong == []
