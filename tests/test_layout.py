"""The layout's rules, read from the source: imports only go down the layers, no import cycles, every package
listed in pyproject.toml, no user doc that points outside the repository."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pegasus_gen", "dope_training", "robot_bridge", "nodes")
# inside pegasus_gen: a subpackage imports only subpackages of a lower rank (equal ranks do not import each other)
PEGASUS_RANKS = {"errors": 0, "__init__": 0, "io": 1, "geometry": 1, "splats": 2, "formats": 2, "render": 3,
                 "assets": 4, "dataset": 5, "scan": 5, "cli": 6}
# across packages: nodes -> robot_bridge | dope_training -> pegasus_gen
PACKAGE_RANKS = {"pegasus_gen": 0, "dope_training": 1, "robot_bridge": 1, "nodes": 2}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules() -> dict[str, Path]:
    """{dotted module name: file} of every module of the four packages."""
    return {module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in the file (function-level imports too); ``from pkg import mod``
    counts as importing ``pkg.mod`` when that is a module."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}:{node.lineno}: relative import (the project imports absolutely)"
            base = node.module
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        found.update(n for n in names if n.split(".")[0] in PACKAGES and n in modules)
    return found


def layer_violation(importer: str, imported: str) -> str | None:
    """Why ``importer`` must not import ``imported``, or None when the rules allow it."""
    a, b = importer.split("."), imported.split(".")
    if a[0] != b[0]:
        if a[:2] == ["pegasus_gen", "cli"]:
            return None  # the composition root
        if PACKAGE_RANKS[b[0]] >= PACKAGE_RANKS[a[0]]:
            return f"{a[0]} may not import {b[0]}"
        return None
    if a[0] != "pegasus_gen" or len(a) < 2 or len(b) < 2 or a[1] == b[1]:
        return None
    if PEGASUS_RANKS[b[1]] >= PEGASUS_RANKS[a[1]]:
        return f"pegasus_gen.{a[1]} may not import pegasus_gen.{b[1]}"
    return None


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of the graph as a list of modules (first == last), or None."""
    state, stack = {}, []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def import_graph() -> dict[str, set[str]]:
    modules = project_modules()
    return {name: imports_of(path, modules) - {name} for name, path in modules.items()}


def test_imports_only_go_down_the_layers():
    problems = [f"{a} imports {b}: {why}" for a, targets in import_graph().items() for b in sorted(targets)
                if (why := layer_violation(a, b))]
    assert not problems, "\n".join(problems)


def test_no_import_cycles():
    assert find_cycle(import_graph()) is None


@pytest.mark.parametrize("importer, imported", [
    ("pegasus_gen.splats.cloud", "pegasus_gen.render.renderer"),   # up a layer
    ("pegasus_gen.dataset.view", "pegasus_gen.scan.pipeline"),     # sideways between equal ranks
    ("pegasus_gen.dataset.view", "dope_training.data"),            # generator importing a consumer
    ("robot_bridge.grasp", "dope_training.infer"),                 # robot importing the network
    ("dope_training.infer", "nodes.ros"),
])
def test_the_rule_refuses_imports_against_the_grain(importer, imported):
    assert layer_violation(importer, imported)


@pytest.mark.parametrize("importer, imported", [
    ("pegasus_gen.render.renderer", "pegasus_gen.splats.cloud"),
    ("pegasus_gen.cli.dope", "dope_training.train"),
    ("nodes.robot_node", "robot_bridge.bridge"),
    ("dope_training.data", "pegasus_gen.formats.bop"),
    ("pegasus_gen.scan.capture", "pegasus_gen.assets.demo_library"),
])
def test_the_rule_allows_imports_down(importer, imported):
    assert layer_violation(importer, imported) is None


def test_the_network_and_the_robot_read_datasets_through_formats_not_the_generator():
    problems = [f"{a} imports {b}" for a, targets in import_graph().items()
                if a.split(".")[0] in ("dope_training", "robot_bridge") for b in sorted(targets)
                if b.startswith("pegasus_gen.dataset")]
    assert not problems, "\n".join(problems)


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_pyproject_lists_every_package():
    block = re.search(r"(?ms)^packages = \[(.*?)\]", (ROOT / "pyproject.toml").read_text()).group(1)
    listed = set(re.findall(r'"([\w.]+)"', block))
    found = {module_name(p.parent / "__init__.py") for pkg in PACKAGES for p in (ROOT / pkg).rglob("__init__.py")}
    assert listed == found | {"pegasus_launch"}


def test_every_subpackage_says_what_lives_there():
    for init in (ROOT / "pegasus_gen").glob("*/__init__.py"):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and len(doc.splitlines()) <= 2, init


def test_user_docs_point_nowhere_outside_the_repository():
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted(ROOT.glob("*/README.md"))]
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in docs for n, line in enumerate(p.read_text().splitlines(), 1)
            if "shared/" in line or "../" in line]
    assert (ROOT / "docs" / "DESIGN.md").is_file() and not hits, hits


def test_no_module_is_named_for_how_instead_of_what():
    vague = {"utils", "helpers", "misc", "common"}
    assert not [n for n in project_modules() if n.rpartition(".")[2] in vague]



def source_files() -> list[Path]:
    """The product's Python files: the four packages, the launch files and the benchmarks."""
    return [*project_modules().values(), *sorted((ROOT / "launch").glob("*.py")),
            *sorted((ROOT / "benchmarks").glob("*.py"))]


def test_no_module_is_longer_than_a_screenful_of_screens():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for p in project_modules().values()
            if (n := len(p.read_text().splitlines())) > 450]
    assert not long, long


def test_only_the_simulator_speaks_its_dashboard_sim_commands():
    speakers = [f"{p.relative_to(ROOT)}:{node.lineno}" for p in source_files()
                if p.parent.name != "sim" or p.parent.parent.name != "robot_bridge"
                for node in ast.walk(ast.parse(p.read_text()))
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("sim ")]
    assert not speakers, speakers


def test_the_cells_numbers_are_written_once():
    from robot_bridge.cell import SIM_CELL

    layout = [SIM_CELL.base_in_world, SIM_CELL.camera_eye, SIM_CELL.basket, SIM_CELL.spawn_x, SIM_CELL.spawn_y,
              SIM_CELL.home]

    def numbers(node):
        """The numbers of a literal list or tuple of numbers (negative ones too), else None."""
        values = []
        for e in node.elts:
            if isinstance(e, ast.UnaryOp) and isinstance(e.op, ast.USub) and isinstance(e.operand, ast.Constant):
                values.append(-e.operand.value)
            elif isinstance(e, ast.Constant) and isinstance(e.value, (int, float)) and not isinstance(e.value, bool):
                values.append(e.value)
            else:
                return None
        return values

    copies = [f"{p.relative_to(ROOT)}:{node.lineno}" for p in source_files() if p != ROOT / "robot_bridge" / "cell.py"
              for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, (ast.List, ast.Tuple))
              and (values := numbers(node)) and any(len(values) == len(v) and np.allclose(values, v) for v in layout)]
    assert not copies, copies


def test_module_names_are_not_shared_by_unrelated_modules():
    """A name names one thing: only __main__, command-line ``options`` and the `pegasus` command groups of
    pegasus_gen.cli (named for what they drive) repeat."""
    seen: dict[str, list[str]] = {}
    for name in project_modules():
        parts = name.split(".")
        if name in PACKAGES or parts[:2] == ["pegasus_gen", "cli"] or parts[-1] in ("__main__", "options"):
            continue
        seen.setdefault(parts[-1], []).append(name)
    shared = {k: v for k, v in seen.items() if len(v) > 1}
    assert not shared, shared
