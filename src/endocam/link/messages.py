"""What travels between the controller and the robot: key expressions and ROS 2 messages.

Key expressions are the ROS 2 topic names without their leading ``/``, as
``zenoh-bridge-ros2dds`` routes a topic (``ros2_name_to_key_expr`` in its
``src/ros2_utils.rs``: "a Zenoh key_expr shall not start with a '/'"; with no ``namespace``
configured the key is the name with its first character removed), so ``/PSM3/servo_cp`` is the
key ``PSM3/servo_cp``. Payloads are the messages' ROS 2 CDR serialisation (with its 4-byte
encapsulation header, as DDS carries it and the bridge forwards it), written and read by
``rosbags.typesys`` — no hand-written CDR.

Topics (``ARM``: ``PSM3``, ``ECM``, or ``camera`` for the free camera, as the MCAP export
names them):

robot → controller, once per control step ``k`` (header stamp: the simulation time ``t_k``)
    ``ARM/measured_cp`` (``geometry_msgs/PoseStamped``: for the PSM and the ECM the dVRK's
    tool tip in the arm's base frame, its RCM frame, as a stand-alone dVRK arm reports it;
    for the free camera its optical frame in the world; :class:`endocam.robot.dvrk_frames.
    CrtkFrames`), ``ARM/setpoint_cp`` (the pose the carrier heads for, in the same frames),
    ``ARM/measured_js`` (``sensor_msgs/JointState``, the dVRK's joints; empty for the free
    camera), ``ARM/operating_state``
    (``crtk_msgs/OperatingState``), ``ring/measured_cp`` (the ring as the camera senses it;
    stamped with its capture time), ``PSM1/tip`` / ``PSM2/tip`` (``geometry_msgs/PointStamped``),
    ``endocam/servo_result`` (``std_msgs/Float64MultiArray``: what the carrier did with the
    last command, :data:`SERVO_RESULT_FIELDS`).
controller → robot, once per step, answering the state stamped ``t_k``
    ``endocam/look_distance`` (``std_msgs/Float64``, m: the distance to the point the command
    looks at), ``ARM/servo_cv`` (``geometry_msgs/TwistStamped``, the feed-forward velocity,
    when the policy gives one and the carrier follows it: the free camera), then ``ARM/servo_cp``
    (``geometry_msgs/PoseStamped`` in ``measured_cp``'s frames, stamped ``t_k``): the command
    the robot acts on. The look distance and velocity belong to the
    ``servo_cp`` that follows them (one subscriber per side keeps the sending order).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.geometry import FloatArray
from endocam.robot.actuator import ArmKind
from endocam.robot.dvrk_frames import ARM_NAMESPACES, WORLD_FRAME_ID, crtk_pose_fields

OPERATING_STATE_MSG = """std_msgs/Header header
string state
bool is_homed
bool is_busy
"""
"""``crtk_msgs/msg/OperatingState`` (CRTK's definition; not among ROS 2's standard messages)."""
OPERATING_STATE = "crtk_msgs/msg/OperatingState"

ENABLED = "ENABLED"
"""CRTK state: servoing, following commands."""
PAUSED = "PAUSED"
"""CRTK state: the watchdog stopped servoing; the arm holds its pose."""
DISABLED = "DISABLED"
"""CRTK state: the episode has ended; no command is acted on."""

SERVO_RESULT_FIELDS = ("status", "reachable", "guard", "position_error_m", "orientation_error_rad")
"""The ``endocam/servo_result`` array: ``ActuatorStatus``, reachable, ``GuardAction`` (as their
indices in the enums' order), and the conceded goal, m and rad."""

NS_PER_S = 1_000_000_000


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(OPERATING_STATE_MSG, OPERATING_STATE))
    return store


class Keys(NamedTuple):
    """The key expressions of one carrier (see the module's topic list)."""

    measured_cp: str
    setpoint_cp: str
    measured_js: str
    operating_state: str
    servo_cp: str
    servo_jp: str
    servo_cv: str
    ring: str
    tip1: str
    tip2: str
    servo_result: str

    @classmethod
    def of(cls, kind: ArmKind) -> Keys:
        """The keys of carrier ``kind``: ROS 2 topic names without the leading ``/``."""
        arm = ARM_NAMESPACES[kind]
        return cls(
            f"{arm}/measured_cp",
            f"{arm}/setpoint_cp",
            f"{arm}/measured_js",
            f"{arm}/operating_state",
            f"{arm}/servo_cp",
            f"{arm}/servo_jp",
            f"{arm}/servo_cv",
            "ring/measured_cp",
            "PSM1/tip",
            "PSM2/tip",
            "endocam/servo_result",
        )


def stamp_ns(t: float) -> int:
    """A time ``t`` (s) as integer nanoseconds (``builtin_interfaces/Time``'s resolution)."""
    return round(t * NS_PER_S)


class Codec:
    """ROS 2 CDR coding of the link's messages (``rosbags.typesys``, ROS 2 Humble's types).

    Every ``decode_*`` raises ``ValueError`` on a payload that is not the message it names.
    """

    def __init__(self) -> None:
        self.store = _typestore()
        self.t = self.store.types
        self._pose = self.t["geometry_msgs/msg/Pose"]
        self._pose_stamped = self.t["geometry_msgs/msg/PoseStamped"]
        self._point = self.t["geometry_msgs/msg/Point"]
        self._quat = self.t["geometry_msgs/msg/Quaternion"]
        self._time = self.t["builtin_interfaces/msg/Time"]
        self._header_t = self.t["std_msgs/msg/Header"]

    def _header(self, ns: int, frame_id: str = WORLD_FRAME_ID) -> Any:
        return self._header_t(
            stamp=self._time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S), frame_id=frame_id
        )

    def _encode(self, msg: Any, typename: str) -> bytes:
        return bytes(self.store.serialize_cdr(msg, typename))

    def _decode(self, data: bytes, typename: str) -> Any:
        try:
            return self.store.deserialize_cdr(data, typename)
        except Exception as exc:  # rosbags raises several kinds on a malformed payload
            raise ValueError(f"not a {typename}: {exc}") from exc

    def pose(self, T: FloatArray, ns: int, frame_id: str = WORLD_FRAME_ID) -> bytes:
        """``geometry_msgs/PoseStamped`` of the pose ``T`` (4, 4), m, in ``frame_id``, at ``ns``.

        Its fields are :func:`endocam.robot.dvrk_frames.crtk_pose_fields`'s, as in MCAP files.
        """
        px, py, pz, x, y, z, w = crtk_pose_fields(T)
        msg = self._pose_stamped(
            header=self._header(ns, frame_id),
            pose=self._pose(
                position=self._point(x=px, y=py, z=pz),
                orientation=self._quat(x=x, y=y, z=z, w=w),
            ),
        )
        return self._encode(msg, "geometry_msgs/msg/PoseStamped")

    def decode_pose(self, data: bytes, frame_id: str | None = None) -> tuple[FloatArray, int]:
        """The pose (4, 4), m, and stamp (ns) of a ``PoseStamped``; ``ValueError`` if malformed.

        Raises ``ValueError`` also for a non-finite value, a quaternion far from unit length,
        or (given ``frame_id``) a pose whose ``header.frame_id`` is not ``frame_id``.
        """
        return self.decode_poses([(data, frame_id)])[0]

    def decode_poses(
        self, payloads: Sequence[tuple[bytes, str | None]]
    ) -> list[tuple[FloatArray, int]]:
        """:meth:`decode_pose` of each ``(data, frame_id)``, with one scipy conversion for all.

        The same poses to the bit as one by one (scipy converts each quaternion alone).
        """
        fields, stamps = [], []
        for data, frame_id in payloads:
            msg = self._decode(data, "geometry_msgs/msg/PoseStamped")
            if frame_id is not None and msg.header.frame_id != frame_id:
                raise ValueError(f"pose in frame {msg.header.frame_id!r}, not {frame_id!r}")
            p, q = msg.pose.position, msg.pose.orientation
            v = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)  # Python floats: no small-array overhead
            if not all(map(math.isfinite, v)):
                raise ValueError("pose with a non-finite value")
            if abs(math.hypot(*v[3:]) - 1.0) > QUAT_NORM_TOL:
                raise ValueError("pose whose quaternion is not of unit length")
            fields.append(v)
            stamps.append(_ns(msg.header))
        R = Rotation.from_quat([v[3:] for v in fields]).as_matrix()  # normalised, as before
        poses = []
        for v, R_k, ns in zip(fields, R, stamps, strict=True):
            T = np.empty((4, 4))
            T[:3, :3] = R_k
            T[:3, 3] = v[:3]
            T[3] = (0.0, 0.0, 0.0, 1.0)
            poses.append((T, ns))
        return poses

    def point(self, p: FloatArray, ns: int) -> bytes:
        """``geometry_msgs/PointStamped`` of ``p`` (3,), m."""
        msg = self.t["geometry_msgs/msg/PointStamped"](
            header=self._header(ns), point=self._point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
        )
        return self._encode(msg, "geometry_msgs/msg/PointStamped")

    def decode_point(self, data: bytes) -> FloatArray:
        """The point (3,), m, of a ``PointStamped``."""
        p = self._decode(data, "geometry_msgs/msg/PointStamped").point
        return np.array([p.x, p.y, p.z], dtype=float)

    def joints(self, names: tuple[str, ...], q: FloatArray, ns: int) -> bytes:
        """``sensor_msgs/JointState`` with ``name`` and ``position`` (rad / m)."""
        empty = np.zeros(0)
        msg = self.t["sensor_msgs/msg/JointState"](
            header=self._header(ns),
            name=list(names),
            position=np.asarray(q, dtype=np.float64),
            velocity=empty,
            effort=empty,
        )
        return self._encode(msg, "sensor_msgs/msg/JointState")

    def decode_joints(self, data: bytes) -> FloatArray:
        """The positions (n,) of a ``JointState``."""
        return np.array(self._decode(data, "sensor_msgs/msg/JointState").position, dtype=float)

    def decode_joint_command(self, data: bytes) -> tuple[FloatArray, int]:
        """The positions (n,) and stamp (ns) of a ``JointState``; ``ValueError`` if not finite."""
        msg = self._decode(data, "sensor_msgs/msg/JointState")
        q = np.array(msg.position, dtype=float)
        if not np.all(np.isfinite(q)):
            raise ValueError("joint positions with a non-finite value")
        return q, _ns(msg.header)

    def twist(self, v: FloatArray, ns: int) -> bytes:
        """``geometry_msgs/TwistStamped`` of ``v`` (6,): linear m/s, then angular rad/s, world."""
        V = self.t["geometry_msgs/msg/Vector3"]
        msg = self.t["geometry_msgs/msg/TwistStamped"](
            header=self._header(ns),
            twist=self.t["geometry_msgs/msg/Twist"](
                linear=V(x=float(v[0]), y=float(v[1]), z=float(v[2])),
                angular=V(x=float(v[3]), y=float(v[4]), z=float(v[5])),
            ),
        )
        return self._encode(msg, "geometry_msgs/msg/TwistStamped")

    def decode_twist(self, data: bytes) -> tuple[FloatArray, int]:
        """The velocity (6,) and stamp (ns) of a ``TwistStamped``; ``ValueError`` if not finite."""
        msg = self._decode(data, "geometry_msgs/msg/TwistStamped")
        a, b = msg.twist.linear, msg.twist.angular
        v = np.array([a.x, a.y, a.z, b.x, b.y, b.z], dtype=float)
        if not np.all(np.isfinite(v)):
            raise ValueError("twist with a non-finite value")
        return v, _ns(msg.header)

    def float64(self, x: float) -> bytes:
        """``std_msgs/Float64``."""
        return self._encode(self.t["std_msgs/msg/Float64"](data=float(x)), "std_msgs/msg/Float64")

    def decode_float64(self, data: bytes) -> float:
        """The value of a ``std_msgs/Float64``."""
        return float(self._decode(data, "std_msgs/msg/Float64").data)

    def array(self, values: FloatArray) -> bytes:
        """``std_msgs/Float64MultiArray`` (no layout: a plain vector)."""
        layout = self.t["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        msg = self.t["std_msgs/msg/Float64MultiArray"](
            layout=layout, data=np.asarray(values, dtype=np.float64)
        )
        return self._encode(msg, "std_msgs/msg/Float64MultiArray")

    def decode_array(self, data: bytes) -> FloatArray:
        """The values of a ``std_msgs/Float64MultiArray``."""
        return np.array(self._decode(data, "std_msgs/msg/Float64MultiArray").data, dtype=float)

    def operating_state(self, state: str, busy: bool, ns: int) -> bytes:
        """``crtk_msgs/OperatingState`` (always homed: the simulated arm needs no homing)."""
        msg = self.t[OPERATING_STATE](
            header=self._header(ns), state=state, is_homed=True, is_busy=busy
        )
        return self._encode(msg, OPERATING_STATE)

    def decode_operating_state(self, data: bytes) -> tuple[str, int]:
        """The state and stamp (ns) of a ``crtk_msgs/OperatingState``."""
        msg = self._decode(data, OPERATING_STATE)
        return str(msg.state), _ns(msg.header)


QUAT_NORM_TOL = 1e-6
"""How far a received quaternion's norm may be from 1 (dimensionless): float64 round-off of a
normalised quaternion is ~1e-16; anything beyond this is not a rotation."""


def _ns(header: Any) -> int:
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)
