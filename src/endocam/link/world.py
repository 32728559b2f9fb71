"""The episode's world as both ends of the link build it from the same options.

The robot process steps the carrier in it and publishes what a rig would measure (the camera,
its joints, the sensed ring, the tips); the controller builds the same world for what a rig
does not publish — the ground truth its run files are scored against (the true ring pose, the
touches) — and checks that the robot's ring matches it before it commands anything.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, NamedTuple

from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec
from endocam.runner.step import EpisodeWorld, episode_world
from endocam.task.trajectory import RingTrajectory, make_trajectory
from endocam.task.wire import Wire

if TYPE_CHECKING:
    import zenoh


class LinkWorld(NamedTuple):
    """An episode's world (``EpisodeWorld``) with what made it."""

    camera: StereoCamera
    wire: Wire
    trajectory: RingTrajectory
    world: EpisodeWorld


def link_world(config: ExperimentConfig, spec: EpisodeSpec) -> LinkWorld:
    """The world of ``spec``'s trajectory under ``config`` (no faults: the link is the fault)."""
    camera = config.camera.stereo()
    wire = Wire(config.task.wire)
    trajectory = make_trajectory(
        config.task, spec.trajectory, spec.control_points, spec.seed, wire=wire
    )
    return LinkWorld(camera, wire, trajectory, episode_world(config, trajectory))


def zenoh_config(endpoint: str, *, listen: bool) -> zenoh.Config:
    """A peer-to-peer Zenoh config on ``endpoint`` (e.g. ``tcp/127.0.0.1:7447``), no scouting.

    The robot listens, the controller connects: with an explicit endpoint no multicast
    discovery is needed (and none is done).
    """
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints" if listen else "connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf
