"""Test-suite settings.

Every hypothesis test draws the same examples on every run: a property test that finds a
failure on one CI run and passes on the next hides the failure; derandomized, a new case shows
up when the code changes, and stays (add it with ``@example``).

Test modules that never call a numba kernel say so with ``pytestmark = pytest.mark.no_kernels``.
`make test` runs them while `endocam compile` fills the kernel cache on the other core (the
Makefile's ``NO_KERNEL_TESTS``). Run that way (``ENDOCAM_TESTS_NO_KERNELS=1``), a marked module
that calls a kernel fails, naming the kernel: the mark is checked, not trusted.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

settings.register_profile("endocam", derandomize=True, database=None)
settings.load_profile("endocam")

NO_KERNELS_ENV = "ENDOCAM_TESTS_NO_KERNELS"
"""Set to 1: every collected test must carry the ``no_kernels`` mark and call no kernel."""


class KernelCalledError(RuntimeError):
    """A test marked ``no_kernels`` called a numba kernel."""


def _refuse_kernels() -> None:
    """Make any numba kernel's first call in this process raise :class:`KernelCalledError`.

    A kernel's first call in a process goes through ``Dispatcher.compile`` whether numba then
    compiles it or loads it from the cache, so this catches every kernel a test calls.
    """
    from numba.core.dispatcher import Dispatcher

    def refuse(self: Dispatcher, sig: object) -> object:
        name = f"{self.py_func.__module__}.{self.py_func.__qualname__}"
        raise KernelCalledError(f"kernel {name} called by a test marked no_kernels")

    Dispatcher.compile = refuse  # type: ignore[method-assign]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "no_kernels: the module calls no numba kernel (run while they compile)"
    )
    if os.environ.get(NO_KERNELS_ENV) == "1":
        _refuse_kernels()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get(NO_KERNELS_ENV) != "1":
        return
    unmarked = sorted(
        {i.nodeid.split("::")[0] for i in items if not i.get_closest_marker("no_kernels")}
    )
    if unmarked:
        raise pytest.UsageError(
            f"{NO_KERNELS_ENV}=1 but not marked no_kernels: {', '.join(unmarked)}"
        )
