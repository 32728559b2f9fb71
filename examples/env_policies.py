"""The built-in camera policies as agents of the Gymnasium env ``endocam/WireChaser-v0``.

Runs each policy on the same noisy trajectory (free camera, twist actions; ``--psm``: the PSM's
joint velocities) and prints their returns side by side, with a do-nothing agent for scale:

    python examples/env_policies.py --duration 60 --seed 1
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import endocam.envs
from endocam.config import ExperimentConfig
from endocam.envs.agents import AGENT_POLICIES, compare_policies, returns_table, run_agent


class Still:
    """A zero action every step: the camera stays where it starts."""

    name = "zero action"

    def reset(self) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.zeros(6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="trajectory length, s")
    parser.add_argument("--seed", type=int, default=1, help="trajectory seed (endocam run --seed)")
    parser.add_argument("--psm", action="store_true", help="joint-velocity actions of the PSM")
    parser.add_argument("--policies", default=",".join(AGENT_POLICIES), help="comma-separated")
    args = parser.parse_args()
    experiment = ExperimentConfig.model_validate(
        {"task": {"trajectory": {"duration": args.duration}}}
    )
    config = endocam.envs.WireChaserEnvConfig(
        experiment=experiment, action="joint_velocity" if args.psm else "twist"
    )
    env = gym.make(endocam.envs.ENV_ID, config=config)
    policies = [p for p in args.policies.split(",") if p]
    rows = [run_agent(env, Still(), 0, args.seed), *compare_policies(env, policies, 0, args.seed)]
    print(returns_table(rows))
    env.close()


if __name__ == "__main__":
    main()
