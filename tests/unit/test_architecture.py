"""The layers of docs/architecture.md hold: who may import whom, module sizes.

Imports are read from the source (every ``import`` and ``from ... import``,
those inside functions included), so a late import counts as much as one at
the top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("jaxround", "agents", "sumo_export")
MAX_LINES = 400

#: What each layer of jaxround may import besides itself (and third parties).
ALLOWED = {
    "jaxround.scenario": set(),
    "jaxround.core": {"jaxround.scenario"},
    "jaxround.sumo_files": {"jaxround.scenario", "jaxround.core"},
    # SUMO's lane-change model and the lane paths, used by the step on
    # two-lane roads
    "jaxround.lanes": {"jaxround.scenario", "jaxround.core", "jaxround.sumo_files"},
    "jaxround.envs": {
        "jaxround.scenario",
        "jaxround.core",
        "jaxround.sumo_files",
        "jaxround.lanes",
    },  # fmt: skip
    "jaxround.analysis": {
        "jaxround.scenario",
        "jaxround.core",
        "jaxround.sumo_files",
        "jaxround.lanes",
        "jaxround.envs",
    },  # fmt: skip
    "jaxround.integrations": {
        "jaxround.scenario",
        "jaxround.core",
        "jaxround.sumo_files",
        "jaxround.lanes",
        "jaxround.envs",
    },  # fmt: skip
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[module_name(path)] = path
    return found


MODULES = modules()


def imported(name: str) -> set[str]:
    """The project's modules that module `name` imports, anywhere in it."""
    tree = ast.parse(MODULES[name].read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert not node.level, f"{name}: the project imports absolutely"
            base = node.module or ""
            # `from pkg import mod` names a module; `from mod import f` does not
            targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target:
                out.add(target)
    out.discard(name)
    return out


def layer_of(name: str) -> str | None:
    for layer in ALLOWED:
        if name == layer or name.startswith(layer + "."):
            return layer
    return None


def closure(start: set[str]) -> set[str]:
    seen, todo = set(), list(start)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(imported(name) - seen)
    return seen


def test_the_import_graph_is_read() -> None:
    assert "jaxround.core.dynamics" in MODULES
    assert "jaxround.core.idm" in imported("jaxround.core.planning")
    assert "jaxround.scenario.config" in imported("sumo_export.scenario")


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_a_layer_imports_only_the_layers_below_it(layer: str) -> None:
    wrong = []
    for name in MODULES:
        if layer_of(name) != layer:
            continue
        for target in imported(name):
            target_layer = layer_of(target) or target.split(".")[0]
            if target_layer == "jaxround":
                target_layer = target
            allowed = ALLOWED[layer] | {layer}
            if not any(
                target_layer == a or target_layer.startswith(a + ".") for a in allowed
            ):
                wrong.append(f"{name} imports {target}")
    assert not wrong, "\n".join(wrong)


def test_what_agents_and_sumo_export_use_of_jaxround_does_not_import_them_back() -> (
    None
):
    used = {
        target
        for name in MODULES
        if name.startswith(("agents", "sumo_export"))
        for target in imported(name)
        if target.startswith("jaxround")
    }
    wrong = sorted(
        f"{name} (used by agents or sumo_export) reaches {target}"
        for name in closure(used)
        if name.startswith("jaxround")
        for target in imported(name)
        if target.startswith(("agents", "sumo_export"))
    )
    assert not wrong, "\n".join(wrong)


def test_no_module_is_over_400_lines() -> None:
    long = {
        name: n
        for name, path in MODULES.items()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert not long, long


def test_the_slot_sizing_does_not_import_the_environment_back() -> None:
    """`jaxround.envs.roundabout` imports `slots`; `slots` measures through
    the environment factory its caller gives, so no import circle."""
    assert "jaxround.envs.slots" in imported("jaxround.envs.roundabout")
    assert "jaxround.envs.roundabout" not in closure({"jaxround.envs.slots"})


def test_sumo_processes_import_no_jax_at_the_top() -> None:
    """`jaxround.sumo_files.processes` starts SUMO's workers: it reads JAX's
    state only where JAX is imported already."""
    tree = ast.parse(MODULES["jaxround.sumo_files.processes"].read_text())
    top = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    names = {a.name for n in top for a in n.names} | {
        n.module for n in top if isinstance(n, ast.ImportFrom) and n.module
    }
    assert not any(name.split(".")[0] == "jax" for name in names)
