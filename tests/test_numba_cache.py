"""The kernel cache's folder follows the kernels' source, and only it."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import endocam
from endocam._numba_cache import (
    HASH_CHARS,
    cache_dir,
    hashed_modules,
    kernel_modules,
    module_path,
    source_hash,
)

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

PACKAGE = Path(endocam.__file__).parent
COMPILED = {"njit", "jit", "register_jitable", "intrinsic", "overload", "overload_method"}
"""Decorators that make a function compiled (numba's, as endocam uses them)."""


B_SOURCE = "import numba.extending\n\nfrom pkg.consts import C\n\nY = 2\n"


def _package(root: Path) -> Path:
    pkg = root / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("from numba import njit\n\nX = 1\n")
    (pkg / "consts.py").write_text("C = 1.0  # a constant a kernel module imports\n")
    (pkg / "sub" / "b.py").write_text(B_SOURCE)
    (pkg / "app.py").write_text("Z = 3  # no kernel here\n")
    (pkg / "notes.txt").write_text("not source\n")
    return pkg


def test_the_hash_changes_with_a_kernel_module_and_only_with_one(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    first = source_hash(pkg)
    assert len(first) == HASH_CHARS and source_hash(pkg) == first
    assert [p.name for p in kernel_modules(pkg)] == ["a.py", "b.py"]
    assert [p.name for p in hashed_modules(pkg)] == ["a.py", "consts.py", "b.py"]
    (pkg / "notes.txt").write_text("edited\n")  # not a .py file
    (pkg / "app.py").write_text("Z = 4  # an app module: no compiled code to go stale\n")
    assert source_hash(pkg) == first
    (pkg / "sub" / "b.py").write_text(B_SOURCE.replace("2", "3"))  # a kernel's constant
    second = source_hash(pkg)
    assert second != first
    (pkg / "consts.py").write_text("C = 2.0  # a constant a kernel module imports\n")
    assert source_hash(pkg) not in (first, second)
    (pkg / "consts.py").write_text("C = 1.0  # a constant a kernel module imports\n")
    assert source_hash(pkg) == second
    (pkg / "sub" / "b.py").rename(pkg / "b.py")  # same bytes, another module
    assert source_hash(pkg) not in (first, second)


def test_editing_the_study_app_keeps_the_folder_and_editing_a_kernel_changes_it(
    tmp_path: Path,
) -> None:
    """On a copy of endocam's own source: a study module, then the touch kernels."""
    copy = tmp_path / "endocam"
    for path in PACKAGE.rglob("*.py"):
        target = copy / path.relative_to(PACKAGE)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(path.read_bytes())
    first = source_hash(copy)
    assert first == source_hash(PACKAGE)
    for name in ("study/app.py", "cli/run.py", "runner/outputs.py"):
        with (copy / name).open("a") as f:
            f.write("\n# edited\n")
    assert source_hash(copy) == first
    with (copy / "task" / "touches.py").open("a") as f:
        f.write("\n# edited\n")
    assert source_hash(copy) != first


def _decorator_name(node: ast.expr) -> str:
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def _imports(tree: ast.Module) -> dict[str, tuple[str, str | None]]:
    """Local name -> (endocam module, name in it; ``None``: the module itself)."""
    found: dict[str, tuple[str, str | None]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                found[alias.asname or alias.name] = (node.module, alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname:
                    found[alias.asname] = (alias.name, None)
    return {k: v for k, v in found.items() if module_path(PACKAGE, v[0]) is not None}


def _defining_chain(module: str, name: str | None) -> list[Path]:
    """The modules a name passes through, from the one imported from to the one defining it."""
    path = module_path(PACKAGE, module)
    assert path is not None
    if name is None:
        return [path]
    imported = _imports(ast.parse(path.read_text(encoding="utf-8")))
    if name in imported:  # re-exported: follow it
        return [path, *_defining_chain(*imported[name])]
    return [path]


def test_no_kernel_reads_a_name_the_hash_does_not_cover() -> None:
    """Every endocam name a compiled function reads is defined in a hashed module.

    The soundness of :func:`hashed_modules`: numba freezes a kernel's globals into it, so a
    constant from a module outside the hash could go stale in the cache. A name defined in the
    kernel's own module is hashed with it; an imported one must be defined (not re-exported
    from elsewhere) in hashed modules all along its import chain.
    """
    hashed = set(hashed_modules(PACKAGE))
    assert PACKAGE / "task" / "touches.py" in hashed
    assert not any(p.is_relative_to(PACKAGE / "study") for p in hashed)
    kernels = 0
    offenders = []
    for path in kernel_modules(PACKAGE):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        imported = _imports(tree)
        for node in ast.walk(tree):
            if not isinstance(node, ast.FunctionDef):
                continue
            if not any(_decorator_name(d) in COMPILED for d in node.decorator_list):
                continue
            kernels += 1
            names = {n.id for s in node.body for n in ast.walk(s) if isinstance(n, ast.Name)}
            for name in sorted(names & imported.keys()):
                chain = _defining_chain(*imported[name])
                if not all(p in hashed for p in chain):
                    offenders.append(f"{path.relative_to(PACKAGE)}:{node.name}: {name}")
    assert kernels > 50  # the check sees the package's kernels
    assert offenders == []


def _numba_cache_dir(env: dict[str, str]) -> str:
    code = "import endocam, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def test_the_folder_is_under_the_user_cache(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    folder = cache_dir(pkg, {"XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert folder == tmp_path / "xdg" / "endocam" / f"numba-{source_hash(pkg)}"
    assert cache_dir(pkg, {}).parent == Path.home() / ".cache" / "endocam"


def test_importing_endocam_points_numba_at_it_unless_the_user_chose(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    expected = cache_dir(PACKAGE, env)
    assert _numba_cache_dir(env) == str(expected)
    assert expected.is_dir()
    chosen = tmp_path / "mine"
    assert _numba_cache_dir({**env, "NUMBA_CACHE_DIR": str(chosen)}) == str(chosen)


def test_a_cache_folder_without_an_index_file_is_cold(tmp_path: Path) -> None:
    from endocam.runner.precompile import kernels_cached

    assert not kernels_cached({"NUMBA_CACHE_DIR": str(tmp_path)})
    (tmp_path / "control_0" / "x.nbc").parent.mkdir()
    (tmp_path / "control_0" / "x.nbc").write_bytes(b"")  # data without its index: not loadable
    assert not kernels_cached({"NUMBA_CACHE_DIR": str(tmp_path)})
    (tmp_path / "control_0" / "plan.plan_step-10.py311.nbi").write_bytes(b"")
    assert kernels_cached({"NUMBA_CACHE_DIR": str(tmp_path)})
    assert kernels_cached({})  # no folder of endocam's choosing: numba's own, not looked at


def test_commands_that_run_episodes_say_when_they_will_compile(tmp_path: Path) -> None:
    from endocam.cli import build_parser, first_use_note

    cold = {"NUMBA_CACHE_DIR": str(tmp_path)}
    parser = build_parser()
    run = parser.parse_args(["run", "--policy", "endocam", "--trajectory", "noisy", "--out", "r"])
    note = first_use_note(run, cold)
    assert note is not None and str(tmp_path) in note and "compil" in note
    assert "\n" not in note
    for argv in (["demo"], ["sweep", "--out", "w"], ["study", "make", "--out", "s"]):
        assert first_use_note(parser.parse_args(argv), cold) is not None, argv
    for argv in (
        ["check", "r"],
        ["policies"],
        ["compile"],
        ["study", "serve", "--study", "s", "--db", "d"],
    ):
        assert first_use_note(parser.parse_args(argv), cold) is None, argv  # they run none
    (tmp_path / "x.nbi").write_bytes(b"")
    assert first_use_note(run, cold) is None  # warm: nothing to say
