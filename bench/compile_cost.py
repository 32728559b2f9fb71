"""CPU cost of the compiled kernels' first call in a fresh process: compile, or load the cache.

``robot.dh.compose_links`` is compiled by numba (``cache=True``). This prints the import time
of the modules that use it and the CPU time of its first calls on the PSM and ECM chains (one
specialisation each). Run it with an empty cache for the compile cost, then again for the
cached load::

    rm -rf /tmp/nb && NUMBA_CACHE_DIR=/tmp/nb .venv/bin/python bench/compile_cost.py  # compiles
    NUMBA_CACHE_DIR=/tmp/nb .venv/bin/python bench/compile_cost.py                    # loads
"""

from __future__ import annotations

import time


def main() -> None:
    """Print the import and first-call CPU times, s."""
    t0 = time.process_time()
    from endocam.robot.dh import compose_links
    from endocam.robot.ecm import ECM_CHAIN
    from endocam.robot.psm import PSM_CHAIN

    t1 = time.process_time()
    compose_links(PSM_CHAIN, [0.1] * PSM_CHAIN.n_joints)
    compose_links(ECM_CHAIN, [0.1] * ECM_CHAIN.n_joints)
    t2 = time.process_time()
    print(f"import {t1 - t0:.3f} s, first calls (PSM + ECM) {t2 - t1:.3f} s CPU")


if __name__ == "__main__":
    main()
