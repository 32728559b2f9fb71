"""The kernel cache's folder follows the source: an edit anywhere in the package gives a new one."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from endocam._numba_cache import HASH_CHARS, cache_dir, source_hash


def _package(root: Path) -> Path:
    pkg = root / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("X = 1\n")
    (pkg / "sub" / "b.py").write_text("Y = 2\n")
    (pkg / "notes.txt").write_text("not source\n")
    return pkg


def test_the_hash_changes_with_any_source_file_and_only_with_source(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    first = source_hash(pkg)
    assert len(first) == HASH_CHARS and source_hash(pkg) == first
    (pkg / "notes.txt").write_text("edited\n")  # not a .py file
    assert source_hash(pkg) == first
    (pkg / "sub" / "b.py").write_text("Y = 3\n")  # a constant another file's kernel may inline
    second = source_hash(pkg)
    assert second != first
    (pkg / "sub" / "b.py").rename(pkg / "b.py")  # same bytes, another module
    assert source_hash(pkg) not in (first, second)


def test_the_folder_is_under_the_user_cache(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    folder = cache_dir(pkg, {"XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert folder == tmp_path / "xdg" / "endocam" / f"numba-{source_hash(pkg)}"
    assert cache_dir(pkg, {}).parent == Path.home() / ".cache" / "endocam"


def _numba_cache_dir(env: dict[str, str]) -> str:
    code = "import endocam, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def test_importing_endocam_points_numba_at_it_unless_the_user_chose(tmp_path: Path) -> None:
    import endocam

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    expected = cache_dir(Path(endocam.__file__).parent, env)
    assert _numba_cache_dir(env) == str(expected)
    assert expected.is_dir()
    chosen = tmp_path / "mine"
    assert _numba_cache_dir({**env, "NUMBA_CACHE_DIR": str(chosen)}) == str(chosen)
