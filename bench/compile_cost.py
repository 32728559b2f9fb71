"""CPU cost of the compiled kernels' first calls in a fresh process: compile, or load the cache.

The control loop's kernels are compiled by numba (``cache=True``; docs/conventions.md,
"Compiled kernels"). This prints the import time of the modules that hold them and the CPU
time of the first calls an episode makes: the link product (PSM and ECM chains), both arms'
IK, the wire's nearest-point query and the clearance guard's queries and detour. Run it with
an empty cache for the compile cost, then again for the cached load::

    rm -rf /tmp/nb && NUMBA_CACHE_DIR=/tmp/nb .venv/bin/python bench/compile_cost.py  # compiles
    NUMBA_CACHE_DIR=/tmp/nb .venv/bin/python bench/compile_cost.py                    # loads
"""

from __future__ import annotations

import time

import numpy as np


def main() -> None:
    """Print the import and first-call CPU times, s."""
    t0 = time.process_time()
    from endocam.config import ExperimentConfig
    from endocam.robot import ECM, PSM
    from endocam.robot.dh import compose_links, pose12_from_matrix
    from endocam.task.wire import Wire

    t1 = time.process_time()
    psm, ecm = PSM(), ECM()
    compose_links(psm.chain, [0.1] * psm.n_joints)
    compose_links(ecm.chain, [0.1] * ecm.n_joints)
    t2 = time.process_time()
    for arm in (psm, ecm):
        q = 0.5 * (arm.lower + arm.upper)
        T = arm.forward(q)
        arm.exact12_unchecked(pose12_from_matrix(T), q)
        arm.solve_unchecked(T, q)
    t3 = time.process_time()
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    guard = cfg.controller.workspace(rcm, wire.point(0.5 * wire.length), wire).keep_out
    assert guard is not None
    p = wire.point(0.5 * wire.length)
    wire.nearest_surface((p + 0.01).tolist())
    guard.first_outside(np.array([p + 0.02]), 1)
    up = np.array([0.0, 0.0, 0.02])  # m: from above the wire to below it
    guard.detour((p + up).tolist(), (p - up).tolist())
    t4 = time.process_time()
    print(
        f"import {t1 - t0:.3f} s; first calls: link product {t2 - t1:.3f} s, IK (PSM + ECM) "
        f"{t3 - t2:.3f} s, wire and clearance {t4 - t3:.3f} s; total {t4 - t0:.3f} s CPU"
    )


if __name__ == "__main__":
    main()
