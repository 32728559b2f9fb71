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
from endocam.envs.agents import AGENT_POLICIES, AgentReturn, compare_policies, returns_table


def still(env: gym.Env, seed: int, trajectory_seed: int) -> AgentReturn:
    """A zero action every step: the camera stays where it starts."""
    env.reset(seed=seed, options={"trajectory_seed": trajectory_seed})
    total, unsafe, errors, done = 0.0, 0, [], False
    while not done:
        _, reward, terminated, truncated, info = env.step(np.zeros(6))
        total += reward
        unsafe += info["unsafe"]
        errors.append(
            (info["image_error_px"], info["center_error_mm"], info["orientation_error_deg"])
        )
        done = terminated or truncated
    img, mm, deg = np.mean(errors, axis=0)
    return AgentReturn("zero action", total, float(img), float(mm), float(deg), unsafe)


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
    rows = [still(env, 0, args.seed), *compare_policies(env, policies, 0, args.seed)]
    print(returns_table(rows))
    env.close()


if __name__ == "__main__":
    main()
