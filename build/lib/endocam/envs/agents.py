"""The built-in camera policies as agents of ``endocam/WireChaser-v0``, and their returns.

A :class:`PolicyAgent` turns each observation back into the policy's :class:`Observation`,
asks the policy for its command and sends the action that moves the environment's set point
to that command (:meth:`WireChaserEnv.action_towards`): the policy, not the agent, decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from endocam.control.types import Observation
from endocam.envs.wire_chaser import WireChaserEnv, pose_from7
from endocam.registry import POLICIES, make_policy

AGENT_POLICIES = tuple(name for name, entry in POLICIES.items() if entry.arm is None)
"""Policies that run on the environment's carrier (``orientation-ecm`` needs the ECM)."""


class Agent(Protocol):
    """What :func:`run_agent` drives: a name, a reset, an action per observation."""

    name: str

    def reset(self) -> None:
        """Start an episode (after ``env.reset``)."""

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(6,) the action for ``obs``."""


class PolicyAgent:
    """A registered policy acting in a :class:`WireChaserEnv`.

    Parameters
    ----------
    env : WireChaserEnv
        The environment (unwrapped or wrapped).
    policy : str
        A name from :data:`AGENT_POLICIES`.
    """

    def __init__(self, env: WireChaserEnv, policy: str) -> None:
        if policy not in AGENT_POLICIES:
            choices = ", ".join(AGENT_POLICIES)
            raise ValueError(f"policy {policy!r} cannot act in the env; choose one of: {choices}")
        self.name = policy
        self.env: WireChaserEnv = env.unwrapped  # type: ignore[assignment]
        self.policy = make_policy(policy, self.env.config.experiment.controller)

    def reset(self) -> None:
        """Start the policy on the environment's new episode (after ``env.reset``)."""
        self.policy.reset(self.env.policy_context())

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(6,) the action that carries out the policy's command for ``obs``."""
        seen = Observation(
            float(obs["time"][0]),
            pose_from7(obs["ring_pose"]),
            pose_from7(obs["camera_pose"]),
            obs["tool_tips"],
            t_ring=float(obs["ring_time"][0]),
        )
        cmd = self.policy.step(seen)
        return self.env.action_towards(cmd.T_world_cam, cmd.d_f)


@dataclass(frozen=True)
class AgentReturn:
    """One agent's episode: its return and its errors (means over the steps).

    Attributes
    ----------
    policy : str
    episode_return : float
        Sum of the rewards.
    image_error_px, center_error_mm, orientation_error_deg : float
        Means of the paper's errors over the episode's steps.
    unsafe_steps : int
        Steps whose action a safety rule clipped or refused.
    """

    policy: str
    episode_return: float
    image_error_px: float
    center_error_mm: float
    orientation_error_deg: float
    unsafe_steps: int


def run_agent(env: WireChaserEnv, agent: Agent, seed: int, trajectory_seed: int) -> AgentReturn:
    """Run one episode of ``agent``: ``reset(seed)`` on the trajectory of ``trajectory_seed``."""
    obs, _ = env.reset(seed=seed, options={"trajectory_seed": trajectory_seed})
    agent.reset()
    total, unsafe = 0.0, 0
    errors: list[tuple[float, float, float]] = []
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(agent.act(obs))
        total += reward
        unsafe += bool(info["unsafe"])
        errors.append(
            (info["image_error_px"], info["center_error_mm"], info["orientation_error_deg"])
        )
        done = terminated or truncated
    img, mm, deg = (float(v) for v in np.mean(errors, axis=0))
    return AgentReturn(agent.name, total, img, mm, deg, unsafe)


def compare_policies(
    env: WireChaserEnv, policies: Sequence[str], seed: int = 0, trajectory_seed: int = 1
) -> list[AgentReturn]:
    """Every policy as an agent on the same trajectory: their returns side by side."""
    return [run_agent(env, PolicyAgent(env, p), seed, trajectory_seed) for p in policies]


def returns_table(rows: Sequence[AgentReturn]) -> str:
    """A Markdown table of :func:`compare_policies`' rows."""
    lines = [
        "| policy | return | image error (px) | 3D error (mm) | orientation error (deg) "
        "| unsafe steps |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.policy} | {r.episode_return:.1f} | {r.image_error_px:.1f} | "
            f"{r.center_error_mm:.2f} | {r.orientation_error_deg:.2f} | {r.unsafe_steps} |"
        )
    return "\n".join(lines)
