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


def test_control_imports_no_robot_implementation_or_simulator() -> None:
    """control/ may name the carriers (robot.actuator, a numpy-only leaf) and nothing else."""
    for p in (SRC / "control").glob("*.py"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                mod = node.module
                assert not mod.startswith(("endocam.sim", "endocam.runner", "mujoco")), (p, mod)
                if mod.startswith("endocam.robot"):
                    assert mod == "endocam.robot.actuator", (p, mod)
