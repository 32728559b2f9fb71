"""Test-suite settings.

Every hypothesis test draws the same examples on every run: a property test that finds a
failure on one CI run and passes on the next hides the failure; derandomized, a new case shows
up when the code changes, and stays (add it with ``@example``).

Test modules that never call a numba kernel say so with ``pytestmark = pytest.mark.no_kernels``.
`make test` runs them while `endocam compile` fills the kernel cache on the other core (the
Makefile's ``NO_KERNEL_TESTS``). Run that way (``ENDOCAM_TESTS_NO_KERNELS=1``), a marked module
that calls a kernel fails, naming the kernel: the mark is checked, not trusted.

The modules in ``SLOW_FIRST`` run first, whole and in that order: with two xdist workers
(``--dist worksteal``) a long module that starts last is the suite's tail, with one worker idle.
The order changes no test.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

settings.register_profile("endocam", derandomize=True, database=None)
settings.load_profile("endocam")

SLOW_FIRST = (
    "test_study_make.py",
    "test_sweep.py",
    "test_sim_arm.py",
    "test_check.py",
    "test_robot_kinematics.py",
    "test_carrier_fast_paths.py",
    "test_tracking_experiment.py",
    "test_legible_paths.py",
    "test_robot_arm.py",
    "test_faults.py",
)
"""Test modules by their CPU time on a warm numba cache, longest first (round 15's durations)."""

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


def _slow_rank(item: pytest.Item) -> int:
    """The module's place in :data:`SLOW_FIRST`; every other module after them."""
    name = item.path.name
    return SLOW_FIRST.index(name) if name in SLOW_FIRST else len(SLOW_FIRST)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=_slow_rank)  # stable: each module's tests stay together and in their order
    if os.environ.get(NO_KERNELS_ENV) != "1":
        return
    unmarked = sorted(
        {i.nodeid.split("::")[0] for i in items if not i.get_closest_marker("no_kernels")}
    )
    if unmarked:
        raise pytest.UsageError(
            f"{NO_KERNELS_ENV}=1 but not marked no_kernels: {', '.join(unmarked)}"
        )
