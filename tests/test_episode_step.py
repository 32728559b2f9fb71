"""The one episode step (runner and Gymnasium env): the world's rows, what the carrier is told."""

from __future__ import annotations

import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.step import EpisodeLoop, SetPoint, episode_world, start_carrier
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire
from endocam.view import look_distance

DURATION = 0.2  # s: a few control steps
CONFIG = ExperimentConfig.model_validate({"task": {"trajectory": {"duration": DURATION}}})


def _loop(kind: ArmKind) -> EpisodeLoop:
    wire = Wire(CONFIG.task.wire)
    trajectory = make_trajectory(CONFIG.task, TrajectoryKind.NOISY, 71, 2, wire=wire)
    world = episode_world(CONFIG, trajectory)
    carrier = start_carrier(CONFIG, kind, CONFIG.camera.stereo(), wire, world)
    return EpisodeLoop(world, carrier)


def test_the_world_has_a_row_per_control_step() -> None:
    wire = Wire(CONFIG.task.wire)
    trajectory = make_trajectory(CONFIG.task, TrajectoryKind.NOISY, 71, 2, wire=wire)
    world = episode_world(CONFIG, trajectory)
    dt = 1.0 / CONFIG.episode.control_rate
    assert world.n == round(DURATION / dt) + 1
    np.testing.assert_allclose(np.diff(world.t), dt)
    np.testing.assert_array_equal(world.T_world_ring, trajectory.poses(world.t))
    np.testing.assert_array_equal(world.T_world_ring_sensed, trajectory.poses(world.t_ring))
    assert np.all(world.t_ring <= world.t)  # the sensed pose is never from the future


@pytest.mark.parametrize("kind", [ArmKind.FREE, ArmKind.PSM])
def test_the_loop_walks_the_world_and_tells_the_carrier_the_look_distance(kind: ArmKind) -> None:
    loop = _loop(kind)
    d_f = CONFIG.controller.d_f
    T_start = loop.T_world_cam.copy()
    steps = 0
    while not loop.done:
        obs = loop.observation()
        k = loop.k
        assert obs.t == loop.world.t[k] and obs.t_ring == loop.world.t_ring[k]
        np.testing.assert_array_equal(obs.T_world_cam, loop.T_world_cam)
        rec = loop.step(SetPoint(T_start, d_f))  # hold the start view
        assert rec.k == k and loop.k == k + 1
        if kind is ArmKind.FREE:
            assert rec.look_distance == d_f and loop.reach_offset is None
        else:
            sensed = loop.world.T_world_ring_sensed[k]
            assert rec.look_distance == look_distance(T_start, sensed, d_f)
            assert loop.reach_offset is not None
        np.testing.assert_array_equal(loop.T_world_cam, rec.carrier.T_world_cam)
        steps += 1
    assert steps == loop.world.n
    with pytest.raises(RuntimeError, match="ended"):
        loop.step(SetPoint(T_start, d_f))
