"""Where numba caches endocam's compiled kernels: a folder per version of the source.

numba's cache (``cache=True``) is keyed by the source file of the kernel itself: it does not
notice an edit to a ``register_jitable`` helper or a module constant in another file that the
kernel inlined, and would keep loading the stale code (numba's "Notes on Caching"). So, unless
the user has chosen ``NUMBA_CACHE_DIR``, endocam points it at
``$XDG_CACHE_HOME/endocam/numba-<hash>`` (``~/.cache`` without it), the hash being that of every
``.py`` file of the package: any edit gives a fresh folder, so a fresh compile (~30 s of CPU
once), and two checkouts never share stale code. Runs on import, before numba is imported
(``endocam/__init__.py`` imports this module first); if numba is already imported, or the
folder cannot be made, numba's default (``__pycache__`` next to the source) is left in place.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

ENV = "NUMBA_CACHE_DIR"
HASH_CHARS = 16  # hex digits of the source hash in the folder's name


def source_hash(package: Path) -> str:
    """sha256 (first ``HASH_CHARS`` hex digits) of every ``.py`` file under ``package``.

    Files are taken in sorted relative-path order, each as its path and its bytes.
    """
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
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
