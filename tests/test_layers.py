"""The layers hold: the import graph of envs/, baselines/ and replicate/ (imports inside
functions and under TYPE_CHECKING included) has no circle, imports run one way between the
top-level packages and between replicate's subpackages, and no module passes 500 lines."""

from __future__ import annotations

import ast
import graphlib
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("envs", "baselines", "replicate")
# replicate's subpackages and top-level modules, lowest first: each may import only itself
# and those before it.
LAYERS = (
    "errors",
    "stats",
    "demos",
    "store",
    "experts",
    "grids",
    "claims",
    "reports",
    "figures",
    "confirm",
    "cli",
    "__main__",
)
SUBPACKAGES = ("store", "grids", "claims", "reports", "figures", "confirm", "cli")
LONGEST_MODULE = 500


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            found[name.removesuffix(".__init__")] = path
    return found


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules of ours it imports, wherever the import statement stands."""
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = name.split(".")[: None if is_package else -1]
                    parts = parts[: len(parts) - node.level + 1]
                    base = ".".join([*parts, base] if base else parts)
                targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
            else:
                continue
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def test_no_import_circle_counting_imports_inside_functions():
    graph = _imports(_modules())
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as circle:
        raise AssertionError(f"import circle: {' -> '.join(circle.args[1])}") from None


def test_imports_run_one_way_between_packages_and_layers():
    def layer(module: str) -> tuple[int, int]:
        parts = module.split(".")
        inner = LAYERS.index(parts[1]) if parts[0] == "replicate" and len(parts) > 1 else 0
        return PACKAGES.index(parts[0]), inner

    wrong = [
        f"{source} imports {target}"
        for source, targets in _imports(_modules()).items()
        for target in targets
        if layer(target) > layer(source)
    ]
    assert not wrong, "\n".join(sorted(wrong))


def test_replicate_has_subpackages_and_no_module_is_too_long():
    subpackages = {p.parent.name for p in (ROOT / "replicate").glob("*/__init__.py")}
    assert set(SUBPACKAGES) <= subpackages
    long = {
        str(path.relative_to(ROOT)): n
        for path in _modules().values()
        if (n := len(path.read_text().splitlines())) > LONGEST_MODULE
    }
    assert not long, f"modules over {LONGEST_MODULE} lines: {long}"


def test_the_graph_sees_imports_inside_functions():
    # the checks above are only as good as the graph: a function-level import must count
    graph = _imports(_modules())
    assert "replicate.store.carry" in graph["replicate.store.checkpoint_places"]
