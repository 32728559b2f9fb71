"""Faults over the link, in-process on real CDR payloads: duplicated, reordered, malformed.

The robot's acceptance rules (:class:`endocam.link.server.CommandGate`) and the controller's
(:meth:`endocam.link.client.ZenohArm.receive`), fed the messages a faulty link would deliver.
The transport itself, the watchdog, a 0.5 s pause and a killed robot are in ``test_link.py``
(two real processes).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.link.client import LinkLostError, ZenohArm
from endocam.link.messages import ENABLED, PAUSED, Codec, Keys, stamp_ns
from endocam.link.server import LOOK_KEY, CommandGate, JointCommand, Verdict
from endocam.robot.actuator import ActuatorStatus, ArmKind, GuardAction
from endocam.robot.carriers import crtk_frames
from endocam.robot.dvrk_frames import FREE_CAMERA_FRAMES

pytestmark = pytest.mark.no_kernels

DT = 0.01  # s: control period (100 Hz)
LOOK_M = 0.05  # m
ATOL_M = 1e-12  # m: a pose through a quaternion and back, float64 round-off
NOTICE_CPU_S = DT  # s of the controller's CPU: it holds within one control period of noticing
SILENCE_S = 0.05  # s (wall): the controller's silence timeout in these tests
KEYS = Keys.of(ArmKind.FREE)
CODEC = Codec()


def _pose(k: int) -> np.ndarray:
    """A distinct camera pose (4, 4), world, m, for step ``k``."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.01 * k, 0.0]).as_matrix()
    T[:3, 3] = [0.001 * k, 0.0, 0.1]
    return T


def _command(k: int, look: float = LOOK_M) -> list[tuple[str, bytes]]:
    """The messages of step ``k``'s command, in the order the controller sends them."""
    return [
        (LOOK_KEY, CODEC.float64(look)),
        (KEYS.servo_cp, CODEC.pose(_pose(k), stamp_ns(k * DT))),
    ]


def _gate() -> CommandGate:
    return CommandGate(KEYS, JointCommand(ArmKind.FREE, None), FREE_CAMERA_FRAMES, DT)


def _feed(gate: CommandGate, messages: list[tuple[str, bytes]], k: int) -> list[Verdict]:
    return [gate.admit(key, data, k).verdict for key, data in messages]


def test_a_command_for_the_current_step_is_accepted_with_its_parts() -> None:
    gate = _gate()
    twist = np.arange(6.0) * 1e-3
    ns = stamp_ns(3 * DT)
    assert gate.admit(LOOK_KEY, CODEC.float64(0.07), 3).verdict is Verdict.PART
    assert gate.admit(KEYS.servo_cv, CODEC.twist(twist, ns), 3).verdict is Verdict.PART
    a = gate.admit(KEYS.servo_cp, CODEC.pose(_pose(3), ns), 3)
    assert a.verdict is Verdict.ACCEPTED and a.command is not None
    np.testing.assert_allclose(a.command.T_world_cmd, _pose(3), rtol=0, atol=ATOL_M)
    assert a.command.look == 0.07 and a.command.ns == ns
    np.testing.assert_array_equal(a.command.twist, twist)
    assert gate.admit("PSM3/measured_cp", b"", 3).verdict is Verdict.IGNORED


def test_duplicated_commands_are_dropped() -> None:
    gate = _gate()
    assert _feed(gate, _command(0), 0) == [Verdict.PART, Verdict.ACCEPTED]
    # the robot stepped to 1; the link delivers step 0's command again, twice
    assert _feed(gate, _command(0) + _command(0), 1) == [Verdict.PART, Verdict.DROPPED] * 2
    assert _feed(gate, _command(1), 1) == [Verdict.PART, Verdict.ACCEPTED]


def test_reordered_commands_are_never_acted_on_out_of_order() -> None:
    gate = _gate()
    # the next step's command overtakes this one's: dropped, this one's still accepted
    assert _feed(gate, _command(5) + _command(4), 4) == [
        *(Verdict.PART, Verdict.DROPPED),
        *(Verdict.PART, Verdict.ACCEPTED),
    ]
    # a servo_cp overtaking its own look distance: refused, and the late look distance is
    # not paired with anything older; the velocity of another stamp is not used
    look, cp = _command(5)
    assert gate.admit(*cp, 5).verdict is Verdict.REFUSED
    assert "without its look distance" in gate.admit(*cp, 5).why
    assert gate.admit(*look, 5).verdict is Verdict.PART
    stale = CODEC.twist(np.ones(6), stamp_ns(4 * DT))
    assert gate.admit(KEYS.servo_cv, stale, 5).verdict is Verdict.PART
    a = gate.admit(*cp, 5)
    assert a.verdict is Verdict.ACCEPTED and a.command is not None and a.command.twist is None


@pytest.mark.parametrize(
    ("key", "payload", "why"),
    [
        (KEYS.servo_cp, b"\x00\x01\x00\x00garbage", "not a geometry_msgs/msg/PoseStamped"),
        (KEYS.servo_cp, CODEC.pose(_pose(2), stamp_ns(2 * DT))[:-5], "not a geometry_msgs"),
        (KEYS.servo_cp, CODEC.float64(1.0), "not a geometry_msgs"),
        (LOOK_KEY, CODEC.float64(float("nan")), "look distance"),
        (LOOK_KEY, CODEC.float64(2.0), "look distance"),
        (KEYS.servo_cv, CODEC.twist(np.full(6, np.inf), stamp_ns(2 * DT)), "non-finite"),
        (KEYS.servo_jp, CODEC.joints(("j",), np.zeros(1), stamp_ns(2 * DT)), "no joints"),
        (KEYS.servo_cp, CODEC.pose(_pose(2), stamp_ns(2 * DT), "PSM3_base"), "'PSM3_base'"),
    ],
    ids=[
        *("garbage", "truncated", "wrong-type", "nan-look", "far-look", "inf-twist", "jp-free"),
        "cp-frame",
    ],
)
def test_a_malformed_message_is_refused_and_clears_the_pending_command(
    key: str, payload: bytes, why: str
) -> None:
    gate = _gate()
    look, cp = _command(2)
    assert gate.admit(*look, 2).verdict is Verdict.PART
    refused = gate.admit(key, payload, 2)
    assert refused.verdict is Verdict.REFUSED and why in refused.why
    # the look distance sent before the bad message is not carried over to another command
    assert gate.admit(*cp, 2).verdict is Verdict.REFUSED
    assert _feed(gate, [look, cp], 2) == [Verdict.PART, Verdict.ACCEPTED]


# -- the controller's side --------------------------------------------------------------------


def _state(k: int, state: str = ENABLED) -> list[tuple[str, bytes]]:
    """What the free-camera robot publishes at step ``k`` (its operating state last)."""
    ns = stamp_ns(k * DT)
    return [
        (KEYS.measured_js, CODEC.joints((), np.zeros(0), ns)),
        (KEYS.ring, CODEC.pose(np.eye(4), ns)),
        (KEYS.tip1, CODEC.point(np.zeros(3), ns)),
        (KEYS.tip2, CODEC.point(np.ones(3), ns)),
        (KEYS.measured_cp, CODEC.pose(_pose(k), ns)),
        (KEYS.operating_state, CODEC.operating_state(state, True, ns)),
    ]


def _arm(messages: list[tuple[str, bytes]], timeout: float = 5.0) -> ZenohArm:
    arm = ZenohArm(ArmKind.FREE, "tcp/127.0.0.1:1", DT, timeout)  # never connected
    for m in messages:
        arm.inbox.put(m)
    return arm


def test_the_controller_skips_repeated_states_and_malformed_operating_states() -> None:
    bad = (KEYS.operating_state, b"\x00\x01\x00\x00junk")
    arm = _arm(_state(0) + _state(0) + [bad] + _state(1))
    s = arm.receive(1, SILENCE_S)
    assert s.k == 1
    np.testing.assert_allclose(s.T_world_cam, _pose(1), rtol=0, atol=ATOL_M)


@pytest.mark.parametrize(
    ("messages", "match"),
    [
        (_state(2), "jumped past step 1"),  # the robot held while the link was down
        (_state(1, PAUSED), "watchdog held the arm"),
        ([*_state(1)[:4], (KEYS.measured_cp, b"\x00\x01\x00\x00x"), *_state(1)[5:]], "malformed"),
        (_state(1)[:4] + _state(0)[4:5] + _state(1)[5:], "stopped advancing"),
        (
            [
                *_state(1)[:4],
                (KEYS.measured_cp, CODEC.pose(_pose(1), stamp_ns(DT), "ECM_base")),
                *_state(1)[5:],
            ],
            "pose in frame 'ECM_base', not 'world'",
        ),
        (
            [
                *_state(1)[:1],
                (KEYS.ring, CODEC.pose(np.eye(4), stamp_ns(DT), "PSM1_base")),
                *_state(1)[2:],
            ],
            "pose in frame 'PSM1_base', not 'world'",
        ),
    ],
    ids=["jumped", "paused", "malformed-pose", "stale-pose", "cp-frame", "ring-frame"],
)
def test_the_controller_holds_at_once_when_the_robot_held_or_its_state_is_bad(
    messages: list[tuple[str, bytes]], match: str
) -> None:
    arm = _arm(_state(0) + messages)  # a 5 s timeout: raising at once is not the timeout
    arm.receive(0, SILENCE_S)  # the decoders' first use (rosbags builds them) is not timed
    c0 = time.thread_time()
    with pytest.raises(LinkLostError, match=match):
        arm.receive(1, arm.timeout)
    assert time.thread_time() - c0 < NOTICE_CPU_S


def test_the_controller_holds_when_the_robot_is_silent() -> None:
    arm = _arm(_state(0)[:3])  # part of a state, then nothing
    t0 = time.monotonic()
    with pytest.raises(LinkLostError, match="silent"):
        arm.receive(1, SILENCE_S)
    assert time.monotonic() - t0 >= SILENCE_S


class _Sent:
    """A publisher that keeps what it was given (the transport is tested in test_link.py)."""

    def __init__(self, key: str, log: list[tuple[str, bytes]]) -> None:
        self.key, self.log = key, log

    def put(self, data: bytes) -> None:
        self.log.append((self.key, data))


def test_a_step_with_a_malformed_answer_holds_instead_of_crashing() -> None:
    answer = [
        (KEYS.servo_result, CODEC.array(np.array([1.0, 0.0, 1.0, 0.002, 0.01]))),
        (KEYS.setpoint_cp, CODEC.pose(_pose(1), stamp_ns(DT))),
    ]
    sent: list[tuple[str, bytes]] = []
    arm = _arm(_state(0) + answer + _state(1))
    arm.pub = {k: _Sent(k, sent) for k in (LOOK_KEY, KEYS.servo_cv, KEYS.servo_cp)}
    arm.state = arm.receive(0, SILENCE_S)
    out = arm.step(_pose(0), LOOK_M)
    assert out.status is ActuatorStatus.VIEW and out.guard is GuardAction.SLID
    assert not out.reachable and (out.position_error, out.orientation_error) == (0.002, 0.01)
    assert [k for k, _ in sent] == [LOOK_KEY, KEYS.servo_cp]
    assert CODEC.decode_pose(sent[1][1])[1] == stamp_ns(0.0)  # answers state 0
    bad = [(KEYS.servo_result, b"\x00\x01\x00\x00?"), *answer[1:]]
    for m in bad + _state(2):
        arm.inbox.put(m)
    with pytest.raises(LinkLostError, match="answer to step 1 is missing or malformed"):
        arm.step(_pose(1), LOOK_M)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_an_arm_refuses_a_servo_cp_not_in_its_base_frame(kind: ArmKind) -> None:
    """A tip pose in another frame (the world, another arm's base) is refused, never acted on."""
    keys, frames = Keys.of(kind), crtk_frames(kind, np.eye(4), np.eye(4))
    gate = CommandGate(keys, JointCommand(kind, None), frames, DT)
    ns = stamp_ns(4 * DT)
    for wrong in ("world", "PSM3_base" if kind is ArmKind.ECM else "ECM_base", ""):
        assert gate.admit(LOOK_KEY, CODEC.float64(LOOK_M), 4).verdict is Verdict.PART
        refused = gate.admit(keys.servo_cp, CODEC.pose(_pose(4), ns, wrong), 4)
        assert refused.verdict is Verdict.REFUSED
        assert f"pose in frame {wrong!r}, not {frames.frame_id!r}" in refused.why
    assert gate.admit(LOOK_KEY, CODEC.float64(LOOK_M), 4).verdict is Verdict.PART
    a = gate.admit(keys.servo_cp, CODEC.pose(_pose(4), ns, frames.frame_id), 4)
    assert a.verdict is Verdict.ACCEPTED


def test_the_controller_says_why_a_first_state_in_another_frame_is_not_taken() -> None:
    """A robot whose measured_cp names another frame: the controller never starts, and says so."""
    ns = stamp_ns(0.0)
    wrong = [(KEYS.measured_cp, CODEC.pose(_pose(0), ns, "PSM3_base"))]
    arm = _arm(_state(0)[:4] + wrong + _state(0)[5:])
    with pytest.raises(LinkLostError, match=r"refused: .*frame 'PSM3_base', not 'world'"):
        arm.receive(0, SILENCE_S, first=True)


def test_poses_decoded_together_are_the_poses_decoded_alone() -> None:
    """The controller decodes a state's poses in one call: the same bits as one by one."""
    rng = np.random.default_rng(5)
    payloads = []
    for k in range(6):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(rng=rng).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        payloads.append((CODEC.pose(T, stamp_ns(k * DT), "PSM3_base"), "PSM3_base"))
    together = CODEC.decode_poses(payloads)
    for (data, frame), (T, ns) in zip(payloads, together, strict=True):
        T_alone, ns_alone = CODEC.decode_pose(data, frame)
        assert np.array_equal(T, T_alone) and ns == ns_alone
        q = CODEC.store.deserialize_cdr(data, "geometry_msgs/msg/PoseStamped").pose.orientation
        R = Rotation.from_quat(np.array([q.x, q.y, q.z, q.w])).as_matrix()  # scipy, one quat
        assert np.array_equal(T[:3, :3], R)
    with pytest.raises(ValueError, match="pose in frame 'PSM3_base', not 'world'"):
        CODEC.decode_poses([payloads[0], (payloads[1][0], "world")])
