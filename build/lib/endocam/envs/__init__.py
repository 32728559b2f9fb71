"""Gymnasium environments: importing this package registers ``endocam/WireChaser-v0``.

Needs the ``gym`` extra (``pip install endocam[gym]``)::

    import gymnasium as gym
    import endocam.envs

    env = gym.make("endocam/WireChaser-v0")
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - exercised without the extra only
    raise ImportError("endocam.envs needs Gymnasium: pip install endocam[gym]") from exc

from endocam.envs.wire_chaser import (
    ENV_ID,
    ActionKind,
    SafetyEvent,
    WireChaserEnv,
    WireChaserEnvConfig,
)

__all__ = ["ENV_ID", "ActionKind", "SafetyEvent", "WireChaserEnv", "WireChaserEnvConfig"]

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="endocam.envs.wire_chaser:WireChaserEnv")
