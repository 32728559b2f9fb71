"""Where a first run's compile goes: numba's compile CPU per entry point and per module.

Runs one ``endocam`` CLI command in this process with an empty numba cache (a new temporary
``NUMBA_CACHE_DIR``, deleted at the end, unless one is set) and listens to numba's
``numba:compile`` events (its event API, ``numba.core.event``). A compile started while
another is under way is that one's callee: its CPU counts in its caller's *inclusive* time
and in its own module's *exclusive* time. Printed: the command's CPU after the imports, the
compiles' count and total, the entry points (compiles started from Python) by inclusive CPU,
and the modules by exclusive CPU::

    MUJOCO_GL=egl .venv/bin/python bench/compile_profile.py run --policy endocam --arm psm \\
        --trajectory noisy --no-video --out /tmp/first

``NUMBA_OPT=0`` (or 1, 2) in the environment shows what LLVM's optimisation level changes.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

if not os.environ.get("NUMBA_CACHE_DIR"):  # before numba is imported: an empty cache
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="endocam-compile-profile-")
    atexit.register(shutil.rmtree, os.environ["NUMBA_CACHE_DIR"], ignore_errors=True)

from numba.core import event


@dataclass
class Open:
    """A compile under way: what, since when (process CPU, s), and its callees' CPU so far."""

    name: str
    module: str
    start: float
    callees: float = 0.0


@dataclass
class CompileListener(event.Listener):
    """Collects each compile's inclusive and exclusive process CPU, s."""

    stack: list[Open] = field(default_factory=list)
    entries: list[tuple[str, float]] = field(default_factory=list)  # (name, inclusive)
    modules: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    count: int = 0

    def on_start(self, ev: Any) -> None:
        func = getattr(ev.data["dispatcher"], "py_func", None)
        name = getattr(func, "__qualname__", "?")
        module = getattr(func, "__module__", "?")
        self.stack.append(Open(f"{module}.{name}", module, time.process_time()))

    def on_end(self, ev: Any) -> None:
        done = self.stack.pop()
        inclusive = time.process_time() - done.start
        self.count += 1
        self.modules[done.module] += inclusive - done.callees
        if self.stack:
            self.stack[-1].callees += inclusive
        else:
            self.entries.append((done.name, inclusive))


def main(argv: list[str]) -> int:
    """Run ``endocam`` with ``argv`` and print where its compile went."""
    listener = CompileListener()
    event.register("numba:compile", listener)
    import endocam.cli

    start = time.process_time()
    code = endocam.cli.main(argv)
    total = time.process_time() - start
    compiled = sum(t for _, t in listener.entries)
    opt = os.environ.get("NUMBA_OPT", "default")
    print(f"\nNUMBA_OPT={opt}")
    print(f"CPU after the imports {total:.2f} s; {listener.count} compiles, {compiled:.2f} s")
    print(f"{len(listener.entries)} entry points (inclusive CPU, s):")
    for name, t in sorted(listener.entries, key=lambda e: -e[1]):
        print(f"  {t:6.2f}  {name}")
    print("modules (exclusive CPU, s):")
    for module, t in sorted(listener.modules.items(), key=lambda m: -m[1]):
        print(f"  {t:6.2f}  {module}")
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
