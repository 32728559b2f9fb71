"""The layout's promises: the episode loop runs without MuJoCo; only ``endocam.sim`` imports it."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "endocam"

HEADLESS = """
import importlib.abc, sys

class _NoMujoco(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "mujoco" or name.startswith("mujoco."):
            raise ImportError("mujoco is blocked in this test")
        return None

sys.meta_path.insert(0, _NoMujoco())
from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind

for arm in ("free", "psm", "ecm"):
    cfg = ExperimentConfig.model_validate(
        {"task": {"trajectory": {"duration": 1.0}}, "episode": {"arm": arm}}
    )
    r = run_episode(cfg, EpisodeSpec("orientation", TrajectoryKind.NOISY, 36, 1))
    assert len(r.log.t) == 101, len(r.log.t)
assert "mujoco" not in sys.modules
print("headless ok")
"""


def test_episode_loop_runs_with_mujoco_blocked() -> None:
    out = subprocess.run(
        [sys.executable, "-c", HEADLESS], capture_output=True, text=True, check=False
    )
    assert out.returncode == 0, out.stderr
    assert "headless ok" in out.stdout


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module is not None and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_only_sim_imports_mujoco() -> None:
    offenders = [
        str(p.relative_to(SRC))
        for p in SRC.rglob("*.py")
        if "mujoco" in _imports(p) and p.relative_to(SRC).parts[0] != "sim"
    ]
    assert offenders == []
    assert any("mujoco" in _imports(p) for p in (SRC / "sim").glob("*.py"))  # the check can see


def _module(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _endocam_imports(path: Path) -> list[tuple[str, list[str]]]:
    """Every ``endocam`` module ``path`` imports (type-checking imports included), with names."""
    found: list[tuple[str, list[str]]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] == "endocam":
                found.append((node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.split(".")[0] == "endocam"]
    return found


SOURCES = sorted(SRC.rglob("*.py"))
MODULES = {_module(p) for p in SOURCES}
MAX_PARAMETERS = 10  # count: a function that needs more takes a named object (issue 23)
MAX_LINES = 700  # lines: a file over this holds more than one idea (issue 23)


def _target(module: str, name: str) -> str:
    """The module an ``from module import name`` reaches (a submodule, or the module itself)."""
    sub = f"{module}.{name}"
    return sub if sub in MODULES else module


def _graph() -> dict[str, set[str]]:
    return {
        _module(p): {_target(m, n) for m, names in _endocam_imports(p) for n in names or [""]}
        - {_module(p)}
        for p in SOURCES
    }


def test_control_and_robot_do_not_import_each_other_or_the_simulator() -> None:
    """Both sit on ``endocam.workspace``; the registry that pairs them sits above both."""
    for p in SOURCES:
        mod = _module(p)
        for imported, _ in _endocam_imports(p):
            assert not (
                mod.startswith("endocam.control")
                and imported.startswith(
                    ("endocam.robot", "endocam.sim", "endocam.runner", "endocam.registry")
                )
            ), (mod, imported)
            assert not (
                mod.startswith("endocam.robot")
                and imported.startswith(
                    ("endocam.control", "endocam.sim", "endocam.runner", "endocam.registry")
                )
            ), (mod, imported)


def _cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle of ``graph`` (module -> modules it imports), or [] if there is none.

    A package importing its own submodules (``__init__`` re-exports) is not a cycle.
    """
    state: dict[str, int] = {}  # 1: on the current path, 2: finished

    def visit(node: str, path: list[str]) -> list[str]:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt.startswith(node + ".") or nxt not in graph:
                continue
            if state.get(nxt) == 1 and not node.startswith(nxt + "."):
                return [*path, node, nxt]
            if nxt not in state and (found := visit(nxt, [*path, node])):
                return found
        state[node] = 2
        return []

    for module in sorted(graph):
        if module not in state and (found := visit(module, [])):
            return found
    return []


def test_no_import_cycle_type_checking_imports_included() -> None:
    assert _cycle(_graph()) == []


def test_the_cycle_check_can_see_a_cycle() -> None:
    graph = {"endocam.a": {"endocam.b"}, "endocam.b": {"endocam.c"}, "endocam.c": {"endocam.a"}}
    assert _cycle(graph) == ["endocam.a", "endocam.b", "endocam.c", "endocam.a"]
    assert _cycle({"endocam.p": {"endocam.p.q"}, "endocam.p.q": {"endocam.p"}}) == []


def test_no_private_name_is_imported_from_another_module() -> None:
    offenders = [
        f"{_module(p)} imports {m}.{n}"
        for p in SOURCES
        for m, names in _endocam_imports(p)
        for n in names
        if n.startswith("_") and not n.startswith("__")
    ]
    assert offenders == []


def test_no_function_takes_more_than_ten_parameters() -> None:
    offenders = []
    for p in SOURCES:
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                a = node.args
                count = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
                count += (a.vararg is not None) + (a.kwarg is not None)
                if count > MAX_PARAMETERS:
                    offenders.append(f"{p.relative_to(SRC)}:{node.lineno} {node.name} {count}")
    assert offenders == []


def test_no_source_file_is_over_700_lines() -> None:
    sizes = {
        str(p.relative_to(SRC)): len(p.read_text(encoding="utf-8").splitlines()) for p in SOURCES
    }
    assert {k: v for k, v in sizes.items() if v > MAX_LINES} == {}
    assert max(sizes.values()) > MAX_LINES // 4  # the check reads real files
