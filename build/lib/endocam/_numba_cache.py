"""Where numba caches endocam's compiled kernels: a folder per version of the kernels' source.

numba's cache (``cache=True``) is keyed by the source file of the kernel itself: it does not
notice an edit to a ``register_jitable`` helper or a module constant in another file that the
kernel inlined, and would keep loading the stale code (numba's "Notes on Caching"). So, unless
the user has chosen ``NUMBA_CACHE_DIR``, endocam points it at
``$XDG_CACHE_HOME/endocam/numba-<hash>`` (``~/.cache`` without it), the hash being that of the
package's *kernel modules* (those that import numba) and of the modules they import from: an
edit to any of them gives a fresh folder, so a fresh compile, and two checkouts never share
stale code; an edit elsewhere (the study app, the CLI, the runner's outputs) keeps the compiled
kernels.

What the hash covers, and why it is enough: compiled code is made of the compiled functions
themselves (``njit``, ``register_jitable``, ``intrinsic``, ``overload``, ...), the compiled
functions they call, and the globals they read, which numba freezes in as constants. A module
can only define a compiled function if it imports numba, so every compiled function lives in a
kernel module. A kernel's globals are its own module's constants and helpers, or names its
module imports from another endocam module (``camera.MIN_DEPTH`` in the image-window kernel):
so the hash covers the kernel modules and the endocam modules they import from
(:func:`hashed_modules`), found by reading the import lines (a regular expression: this runs on
every import of endocam). A name imported from such a module must be defined there, not
re-exported from a third module, which the hash would miss: ``tests/test_numba_cache.py``
checks that on the source, for every name a kernel reads.

Runs on import, before numba is imported (``endocam/__init__.py`` imports this module first);
if numba is already imported, or the folder cannot be made, numba's default (``__pycache__``
next to the source) is left in place.
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
from pathlib import Path

ENV = "NUMBA_CACHE_DIR"
HASH_CHARS = 16  # hex digits of the source hash in the folder's name
IMPORTS_NUMBA = re.compile(rb"^[ \t]*(?:from|import)[ \t]+numba\b", re.MULTILINE)
"""A line that imports numba (or one of its submodules): the mark of a kernel module."""


IMPORTS_PACKAGE = re.compile(
    rb"^[ \t]*(?:from[ \t]+([\w.]+)[ \t]+import|import[ \t]+([\w.]+))", re.MULTILINE
)
"""An import line; its group 1 or 2 is the imported module's dotted name."""


def kernel_modules(package: Path) -> list[Path]:
    """The ``.py`` files under ``package`` that import numba, in sorted path order."""
    return [p for p in sorted(package.rglob("*.py")) if IMPORTS_NUMBA.search(p.read_bytes())]


def module_path(package: Path, name: str) -> Path | None:
    """The source file of the module ``name`` (dotted) of ``package``, or ``None``."""
    parts = name.split(".")
    if parts[0] != package.name:
        return None
    base = package.joinpath(*parts[1:])
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def hashed_modules(package: Path) -> list[Path]:
    """The kernel modules and the modules of ``package`` they import from, sorted."""
    kernels = kernel_modules(package)
    found = set(kernels)
    for path in kernels:
        for match in IMPORTS_PACKAGE.finditer(path.read_bytes()):
            name = (match.group(1) or match.group(2)).decode()
            source = module_path(package, name)
            if source is not None:
                found.add(source)
    return sorted(found)


def source_hash(package: Path) -> str:
    """sha256 (first ``HASH_CHARS`` hex digits) of :func:`hashed_modules` of ``package``.

    Files are taken in sorted relative-path order, each as its path and its bytes.
    """
    h = hashlib.sha256()
    for path in hashed_modules(package):
        h.update(path.relative_to(package).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:HASH_CHARS]


def cache_dir(package: Path, env: dict[str, str]) -> Path:
    """The cache folder for this source: ``<XDG_CACHE_HOME or ~/.cache>/endocam/numba-<hash>``."""
    base = Path(env["XDG_CACHE_HOME"]) if env.get("XDG_CACHE_HOME") else Path.home() / ".cache"
    return base / "endocam" / f"numba-{source_hash(package)}"


def configure() -> None:
    """Set ``NUMBA_CACHE_DIR`` for this process and its children (see the module docstring)."""
    if ENV in os.environ or "numba" in sys.modules:
        return
    try:
        folder = cache_dir(Path(__file__).parent, dict(os.environ))
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    os.environ[ENV] = str(folder)


configure()
