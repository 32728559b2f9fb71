"""Proof that a speed-up left the results unchanged: sha256 of whole 60 s episodes' files.

Runs ``endocam run --no-video --trajectory noisy --control-points 71 --seed 1`` for every
built-in moving policy on every carrier (``endocam``, ``orientation``, ``centering`` on the
free camera, the PSM and the ECM, and ``orientation-ecm`` on the ECM) and prints the sha256 of
each run's ``episode.csv`` and ``metrics.json``. ``episode.csv`` holds ``repr(float)``, so equal
hashes mean the same IEEE doubles, bit for bit.

With ``--base SRC`` (the ``src/`` of another checkout, e.g. main before a change: ``git archive
main | tar -x -C /tmp/main``) every case also runs with ``PYTHONPATH=SRC`` and the two are
compared; the exit code is 1 if any file differs. Run (about a minute of CPU per side)::

    MUJOCO_GL=egl .venv/bin/python bench/episode_hashes.py --base /tmp/main/src
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

CASES = (  # (policy, carrier)
    *(
        (policy, arm)
        for arm in ("free", "psm", "ecm")
        for policy in ("endocam", "orientation", "centering")
    ),
    ("orientation-ecm", "ecm"),
)
FILES = ("episode.csv", "metrics.json")
RUN = ("--no-video", "--trajectory", "noisy", "--control-points", "71", "--seed", "1")


def hashes(policy: str, arm: str, src: str | None) -> dict[str, str]:
    """sha256 (hex) of each of :data:`FILES` of one episode, run by the package in ``src``."""
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "endocam.cli", "run", "--policy", policy, "--arm", arm]
        subprocess.run([*cmd, *RUN, "--out", str(out)], env=env, check=True, capture_output=True)
        return {name: hashlib.sha256((out / name).read_bytes()).hexdigest() for name in FILES}


def main() -> int:
    """Print the hashes per case (and base vs this checkout with ``--base``); 1 if any differ."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", help="src/ of the checkout to compare with")
    args = parser.parse_args()
    differ = 0
    for policy, arm in CASES:
        new = hashes(policy, arm, None)
        base = hashes(policy, arm, args.base) if args.base else None
        for name in FILES:
            verdict = (
                "" if base is None else (" identical" if base[name] == new[name] else " DIFFERENT")
            )
            differ += base is not None and base[name] != new[name]
            print(f"{policy}:{arm} {name} {new[name]}{verdict}", flush=True)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
