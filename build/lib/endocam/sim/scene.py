"""MuJoCo model of the wire-chaser world, generated from :class:`TaskConfig` with ``MjSpec``.

Everything that moves is a mocap body (kinematic: poses are set, never simulated), every body,
geom, site, light and camera is named, and no geom collides (``contype = conaffinity = 0``):
touches come from :mod:`endocam.task.touches`, not from MuJoCo contacts.

Bodies and geoms (geom group in brackets, see ``GROUP_*``):

- world: ``board`` plane at z = 0 [0], ``post_left``/``post_right`` cylinders [0], the wire as one
  tube mesh ``wire`` [1], the training box's walls ``wall_back``/``wall_front``/``wall_left``
  (``scene.backdrop_height``) and ``wall_port`` (low, ``scene.backdrop_port_height``, on the
  camera port's side +x) [0] at the board's edges and its lid ``wall_top`` at
  ``scene.backdrop_height`` [0], lights ``key_light`` and ``fill_light`` (no
  shadows: depth shows by shading, the headlight and the board's checker);
- ``ring`` (mocap, pose = ``T_world_ring``): ``ring_torus`` mesh and ``ring_handle`` [2], and PSM1
  holding the handle's end: ``psm1_jaw_a/b``, ``psm1_wrist``, ``psm1_shaft`` [3], site
  ``psm1_tip``;
- ``psm2`` (mocap, at the configured waiting tip): ``psm2_jaw_a/b``, ``psm2_wrist``,
  ``psm2_shaft`` [3], site ``psm2_tip``;
- ``stereo_camera`` (mocap, pose = ``T_world_cam`` in the optical frame) with MuJoCo cameras
  ``left`` and ``right`` at ∓baseline/2 along x, rotated by π about x (optical → MuJoCo camera,
  ``docs/conventions.md``);
- ``observer`` (mocap, no geoms) with the MuJoCo camera ``observer`` (same intrinsics as the
  eyes): a free viewpoint for overview pictures (``WireChaserScene.render_view``).

More mocap bodies (e.g. robot arm links, group ``GROUP_LINK``, see
:mod:`endocam.sim.arm_scene`) are added with :func:`add_mocap_link` before compiling.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from endocam.camera import Eye, StereoCamera
from endocam.geometry import UP, FloatArray, quat_wxyz_from_R, unit_vector
from endocam.task.config import InstrumentConfig, TaskConfig
from endocam.task.layout import psm1_tip_in_ring, psm2_pose
from endocam.task.wire import Wire

GROUP_BOARD = 0  # board and posts
GROUP_WIRE = 1  # the wire's capsules
GROUP_RING = 2  # ring torus and handle
GROUP_INSTRUMENT = 3  # PSM1 and PSM2
GROUP_LINK = 4  # extra mocap links (robot arms)
N_GROUPS = 6  # MuJoCo's number of geom groups

RING_BODY = "ring"
PSM2_BODY = "psm2"
CAMERA_BODY = "stereo_camera"
OBSERVER = "observer"  # mocap body and MuJoCo camera of the free viewpoint
EYE_CAMERAS: tuple[Eye, Eye] = ("left", "right")
TIP_SITES = ("psm1_tip", "psm2_tip")
Q_MJCAM_OPTICAL = (0.0, 1.0, 0.0, 0.0)  # (w, x, y, z): π about x, optical → MuJoCo camera frame
JAW_THICKNESS = 0.8e-3  # m, jaw plate thickness
JAW_WIDTH = 2.5e-3  # m, jaw plate width
WRIST_RADIUS_FRACTION = 0.6  # unitless, wrist radius / shaft radius
BOARD_CHECKER = 0.02  # m, board texture period (two 1 cm squares)
WALL_THICKNESS = 0.004  # m, the training box's walls
BACKDROP_EMISSION = 0.45  # unitless (× its colour), the walls' own glow: evenly lit, shadow-free
WIRE_MESH_SIDES = 12  # count, segments around the wire tube mesh
PRIMITIVE_SLICES = 16  # count, tessellation of capsules/cylinders (MuJoCo default 28: 3x slower)
PRIMITIVE_STACKS = 8  # count, tessellation of capsule caps and spheres
IDEAL_K_RTOL = 1e-9  # unitless, tolerance of the square-pixel / centred-principal-point check


@dataclass(frozen=True)
class GeomSpec:
    """One primitive of a mocap link, in the link body's frame.

    Attributes
    ----------
    name : str
        Unique geom name.
    kind : {"capsule", "cylinder", "box", "sphere"}
        Primitive type.
    size : (1,) to (3,)
        MuJoCo size: radius for capsule/cylinder/sphere (with ``fromto``), half-extents for box, m.
    fromto : (6,) or None
        Segment end points for capsules/cylinders, body frame, m.
    pos : (3,)
        Centre for boxes/spheres, body frame, m.
    quat : (4,)
        Orientation (w, x, y, z) for boxes, body frame.
    rgba : (4,)
        Colour, 0-1.
    """

    name: str
    kind: str
    size: Sequence[float]
    fromto: Sequence[float] | None = None
    pos: Sequence[float] = (0.0, 0.0, 0.0)
    rgba: Sequence[float] = (0.6, 0.6, 0.6, 1.0)
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)


_GEOM_TYPES = {
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
}


def add_geom(body: mujoco.MjsBody, g: GeomSpec, group: int) -> mujoco.MjsGeom:
    """Add the geom ``g`` (sizes in m) to ``body`` in the visual ``group``; returns it."""
    if g.kind not in _GEOM_TYPES:
        raise ValueError(f"geom kind must be one of {sorted(_GEOM_TYPES)}, got {g.kind!r}")
    size = list(g.size) + [0.0] * (3 - len(g.size))
    geom = body.add_geom(
        name=g.name,
        type=_GEOM_TYPES[g.kind],
        size=size,
        rgba=list(g.rgba),
        group=group,
        contype=0,
        conaffinity=0,
    )
    if g.fromto is not None:
        geom.fromto = list(g.fromto)
    else:
        geom.pos = list(g.pos)
        geom.quat = list(g.quat)
    return geom


def add_mocap_link(
    spec: mujoco.MjSpec,
    name: str,
    geoms: Sequence[GeomSpec],
    T_world_link: FloatArray | None = None,
    group: int = GROUP_LINK,
) -> mujoco.MjsBody:
    """Add a named mocap (kinematic) body with primitive geoms, e.g. a robot arm link.

    Parameters
    ----------
    spec : mujoco.MjSpec
        The spec from :func:`build_spec` (before compiling).
    name : str
        Body name, unique.
    geoms : sequence of GeomSpec
        Geoms in the body frame; each named.
    T_world_link : (4, 4), optional
        Initial pose in world, m (identity by default).
    group : int
        Geom group, 0-5 (default ``GROUP_LINK``).

    Returns
    -------
    mujoco.MjsBody
    """
    if not 0 <= group < N_GROUPS:
        raise ValueError(f"group must be in [0, {N_GROUPS}), got {group}")
    T = np.eye(4) if T_world_link is None else np.asarray(T_world_link, dtype=float)
    body = spec.worldbody.add_body(
        name=name, mocap=True, pos=T[:3, 3].tolist(), quat=quat_wxyz_from_R(T[:3, :3]).tolist()
    )
    for g in geoms:
        add_geom(body, g, group)
    return body


def torus_mesh(
    major_radius: float, minor_radius: float, n_major: int, n_minor: int
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """Closed torus triangle mesh in the ring frame (core circle in the x-y plane).

    Parameters
    ----------
    major_radius, minor_radius : float
        Core-circle and tube radii, m.
    n_major, n_minor : int
        Segments around the core circle and around the tube (≥ 3).

    Returns
    -------
    vertices : (n_major · n_minor, 3)
        m.
    faces : (2 · n_major · n_minor, 3) int
        Counter-clockwise seen from outside (outward normals).
    normals : (n_major · n_minor, 3)
        Unit outward vertex normals.
    """
    if min(n_major, n_minor) < 3:
        raise ValueError("n_major and n_minor must be ≥ 3")
    u = np.linspace(0.0, 2.0 * math.pi, n_major, endpoint=False)[:, None]
    v = np.linspace(0.0, 2.0 * math.pi, n_minor, endpoint=False)[None, :]
    normals = np.stack(
        [
            np.cos(u) * np.cos(v),
            np.sin(u) * np.cos(v),
            np.broadcast_to(np.sin(v), (n_major, n_minor)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    centres = np.stack([np.cos(u), np.sin(u), np.zeros_like(u)], axis=-1)
    centres = np.broadcast_to(centres * major_radius, (n_major, n_minor, 3)).reshape(-1, 3)
    vertices = centres + minor_radius * normals
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    return vertices, faces, normals


def tube_mesh(
    centre_line: FloatArray, radius: float, n_sides: int
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """Closed tube triangle mesh around a polyline, capped at both ends.

    Each cross-section is a circle in the plane normal to the local tangent; its frame is
    built from world up (or world y where the tangent is vertical), so the mesh has no twist
    for a wire that never runs vertically.

    Parameters
    ----------
    centre_line : (n, 3)
        Centre-line points, m (n ≥ 2, no repeats).
    radius : float
        Tube radius, m.
    n_sides : int
        Segments around the tube (≥ 3).

    Returns
    -------
    vertices : (n · n_sides + 2, 3)
        m (the last two are the cap centres).
    faces : (2 · (n − 1) · n_sides + 2 · n_sides, 3) int
        Counter-clockwise seen from outside.
    normals : (n · n_sides + 2, 3)
        Unit vertex normals (radial; along ∓tangent at the caps).
    """
    pts = np.asarray(centre_line, dtype=float)
    if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] != 3 or n_sides < 3:
        raise ValueError("centre_line must be (n ≥ 2, 3) and n_sides ≥ 3")
    tangent = np.gradient(pts, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    ref = np.where(np.abs(tangent[:, 2:3]) > 0.99, np.array([0.0, 1.0, 0.0]), UP)
    e1 = np.cross(ref, tangent)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(tangent, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, n_sides, endpoint=False)
    radial = np.cos(phi)[None, :, None] * e1[:, None] + np.sin(phi)[None, :, None] * e2[:, None]
    n = pts.shape[0]
    vertices = np.vstack([(pts[:, None] + radius * radial).reshape(-1, 3), pts[0], pts[-1]])
    normals = np.vstack([radial.reshape(-1, 3), -tangent[0], tangent[-1]])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n_sides), indexing="ij")
    a = i * n_sides + j
    b = i * n_sides + (j + 1) % n_sides
    c = (i + 1) * n_sides + (j + 1) % n_sides
    d = (i + 1) * n_sides + j
    side = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    k = np.arange(n_sides)
    start = np.stack([np.full(n_sides, n * n_sides), (k + 1) % n_sides, k], -1)
    last = (n - 1) * n_sides
    end = np.stack([np.full(n_sides, n * n_sides + 1), last + k, last + (k + 1) % n_sides], -1)
    return vertices, np.vstack([side, start, end]), normals


def _instrument_geoms(
    prefix: str, x0: float, opening: float, gap: float, cfg: InstrumentConfig
) -> list[GeomSpec]:
    """Jaws, wrist and shaft along +x from the tip at ``x0`` (m), in the holding body's frame."""
    geoms = []
    half = 0.5 * cfg.jaw_length
    pivot = x0 + cfg.jaw_length  # jaws hinge at the wrist and reach back to the tip at x0
    for side, sign in (("a", 1.0), ("b", -1.0)):
        ang = sign * opening  # jaw a opens towards +y, jaw b towards -y
        geoms.append(
            GeomSpec(
                f"{prefix}_jaw_{side}",
                "box",
                (half, 0.5 * JAW_THICKNESS, 0.5 * JAW_WIDTH),
                pos=(
                    pivot - half * math.cos(ang),
                    sign * (0.5 * gap + 0.5 * JAW_THICKNESS) + half * math.sin(ang),
                    0.0,
                ),
                quat=(math.cos(0.5 * ang), 0.0, 0.0, -math.sin(0.5 * ang)),
                rgba=cfg.jaw_rgba,
            )
        )
    x_wrist = x0 + cfg.jaw_length
    x_shaft = x_wrist + cfg.wrist_length
    r_wrist = WRIST_RADIUS_FRACTION * cfg.shaft_radius
    geoms.append(
        GeomSpec(
            f"{prefix}_wrist",
            "capsule",
            (r_wrist,),
            fromto=(x_wrist, 0, 0, x_shaft, 0, 0),
            rgba=cfg.jaw_rgba,
        )
    )
    geoms.append(
        GeomSpec(
            f"{prefix}_shaft",
            "cylinder",
            (cfg.shaft_radius,),
            fromto=(x_shaft, 0, 0, x_shaft + cfg.shaft_length, 0, 0),
            rgba=cfg.rgba,
        )
    )
    return geoms


def check_ideal_camera(camera: StereoCamera) -> None:
    """Raise ``ValueError`` unless the intrinsics are what MuJoCo renders from ``fovy``.

    MuJoCo renders square pixels with the principal point at the image centre.
    """
    k = camera.intrinsics
    if not (
        math.isclose(k.fx, k.fy, rel_tol=IDEAL_K_RTOL)
        and math.isclose(k.cx, 0.5 * k.width, rel_tol=IDEAL_K_RTOL)
        and math.isclose(k.cy, 0.5 * k.height, rel_tol=IDEAL_K_RTOL)
    ):
        raise ValueError(
            "camera intrinsics must have fx == fy and the principal point at the image centre "
            "(Intrinsics.from_fovy) to be rendered by MuJoCo"
        )


def build_spec(task_cfg: TaskConfig, camera: StereoCamera) -> mujoco.MjSpec:
    """Generate the wire-chaser ``MjSpec`` (uncompiled; add links, then ``spec.compile()``).

    Parameters
    ----------
    task_cfg : TaskConfig
    camera : StereoCamera
        Ideal intrinsics (see :func:`check_ideal_camera`); ``fovy`` and the image size set the
        MuJoCo cameras and the offscreen buffer.

    Returns
    -------
    mujoco.MjSpec
    """
    check_ideal_camera(camera)
    sc = task_cfg.scene
    spec = mujoco.MjSpec()
    spec.modelname = "wire_chaser"
    vis = spec.visual
    vis.global_.offwidth = max(camera.intrinsics.width, 640)
    vis.global_.offheight = max(camera.intrinsics.height, 480)
    vis.quality.offsamples = 0  # no MSAA: ~20x faster on the software renderer
    vis.quality.shadowsize = 0
    vis.quality.numslices = PRIMITIVE_SLICES
    vis.quality.numstacks = PRIMITIVE_STACKS
    vis.headlight.ambient = [sc.ambient] * 3
    vis.headlight.diffuse = [sc.headlight_diffuse] * 3
    vis.headlight.specular = [0.1] * 3
    spec.stat.extent = 0.3  # m, scene size (sets near/far clipping)
    spec.stat.center = [0.0, 0.0, 0.05]

    _add_board(spec, task_cfg)
    _add_backdrop(spec, task_cfg)
    wire = Wire(task_cfg.wire)
    _add_wire(spec, task_cfg, wire)
    _add_ring_and_psm1(spec, task_cfg)
    T_psm2 = psm2_pose(task_cfg.instruments)
    geoms = _instrument_geoms(
        "psm2", 0.0, task_cfg.instruments.jaw_opening, 0.0, task_cfg.instruments
    )
    psm2 = add_mocap_link(spec, PSM2_BODY, geoms, T_psm2, GROUP_INSTRUMENT)
    psm2.add_site(name=TIP_SITES[1], pos=[0.0, 0.0, 0.0], size=[1e-3, 0, 0], group=5)

    cam = spec.worldbody.add_body(name=CAMERA_BODY, mocap=True, pos=[0.0, 0.0, 0.2])
    fovy_deg = math.degrees(camera.intrinsics.fovy)
    for eye in EYE_CAMERAS:
        p = camera.T_cam_eye(eye)[:3, 3]
        cam.add_camera(name=eye, pos=p.tolist(), quat=list(Q_MJCAM_OPTICAL), fovy=fovy_deg)
    observer = spec.worldbody.add_body(name=OBSERVER, mocap=True, pos=[0.0, -0.3, 0.2])
    observer.add_camera(name=OBSERVER, quat=list(Q_MJCAM_OPTICAL), fovy=fovy_deg)
    for name, direction, diffuse in (
        ("key_light", sc.key_light_direction, sc.key_light_diffuse),
        ("fill_light", sc.fill_light_direction, sc.fill_light_diffuse),
    ):
        d = unit_vector(direction, f"scene.{name}_direction")
        spec.worldbody.add_light(
            name=name,
            type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
            dir=d.tolist(),
            pos=(-0.3 * d).tolist(),
            castshadow=False,
            diffuse=[diffuse] * 3,
            specular=[0.2] * 3,
            ambient=[0.0] * 3,
        )
    return spec


def build_model(task_cfg: TaskConfig, camera: StereoCamera) -> mujoco.MjModel:
    """Compile the wire-chaser scene (see :func:`build_spec`)."""
    return build_spec(task_cfg, camera).compile()


def _add_board(spec: mujoco.MjSpec, task_cfg: TaskConfig) -> None:
    sc = task_cfg.scene
    spec.add_texture(
        name="board_texture",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=list(sc.board_rgba[:3]),
        rgb2=list(sc.board_checker_rgba[:3]),
        width=64,
        height=64,
    )
    mat = spec.add_material(
        name="board_material",
        texrepeat=[sc.board_size[0] / BOARD_CHECKER, sc.board_size[1] / BOARD_CHECKER],
        specular=0.0,
        shininess=0.0,
        reflectance=0.0,
    )
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "board_texture"
    spec.worldbody.add_geom(
        name="board",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.5 * sc.board_size[0], 0.5 * sc.board_size[1], 0.01],
        material="board_material",
        group=GROUP_BOARD,
        contype=0,
        conaffinity=0,
    )


def _add_backdrop(spec: mujoco.MjSpec, task_cfg: TaskConfig) -> None:
    """The training box: four matte walls on the board's edges and a lid (lit, not black)."""
    sc = task_cfg.scene
    hx, hy = 0.5 * sc.board_size[0], 0.5 * sc.board_size[1]
    t = 0.5 * WALL_THICKNESS
    h, hp = sc.backdrop_height, sc.backdrop_port_height
    walls = (  # name, centre, half-extents
        ("wall_left", (-hx - t, 0.0, 0.5 * h), (t, hy + 2 * t, 0.5 * h)),
        ("wall_port", (hx + t, 0.0, 0.5 * hp), (t, hy + 2 * t, 0.5 * hp)),
        ("wall_back", (0.0, hy + t, 0.5 * h), (hx, t, 0.5 * h)),
        ("wall_front", (0.0, -hy - t, 0.5 * h), (hx, t, 0.5 * h)),
        ("wall_top", (0.0, 0.0, h + t), (hx + 2 * t, hy + 2 * t, t)),  # the box's lid
    )
    mat = spec.add_material(
        name="backdrop_material", specular=0.0, shininess=0.0, emission=BACKDROP_EMISSION
    )
    mat.rgba = list(sc.backdrop_rgba)
    for name, pos, size in walls:
        spec.worldbody.add_geom(
            name=name,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=list(pos),
            size=list(size),
            material="backdrop_material",
            group=GROUP_BOARD,
            contype=0,
            conaffinity=0,
        )


def _add_wire(spec: mujoco.MjSpec, task_cfg: TaskConfig, wire: Wire) -> None:
    sc = task_cfg.scene
    verts, faces, normals = tube_mesh(
        wire.polyline(sc.wire_segments + 1), wire.radius, WIRE_MESH_SIDES
    )
    mesh = spec.add_mesh(name="wire_mesh")
    mesh.uservert = verts.ravel().tolist()
    mesh.userface = faces.ravel().tolist()
    mesh.usernormal = normals.ravel().tolist()
    spec.worldbody.add_geom(
        name="wire",
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname="wire_mesh",
        rgba=list(sc.wire_rgba),
        group=GROUP_WIRE,
        contype=0,
        conaffinity=0,
    )
    for name, top, base in zip(
        ("post_left", "post_right"), wire.post_tops, wire.post_bases, strict=True
    ):
        spec.worldbody.add_geom(
            name=name,
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            fromto=np.concatenate([base, top]).tolist(),
            size=[task_cfg.wire.post_radius, 0.0, 0.0],
            rgba=list(sc.post_rgba),
            group=GROUP_BOARD,
            contype=0,
            conaffinity=0,
        )


def _add_ring_and_psm1(spec: mujoco.MjSpec, task_cfg: TaskConfig) -> None:
    ring, sc, ins = task_cfg.ring, task_cfg.scene, task_cfg.instruments
    verts, faces, normals = torus_mesh(ring.major_radius, ring.minor_radius, *sc.ring_mesh_segments)
    mesh = spec.add_mesh(name="ring_mesh")
    mesh.uservert = verts.ravel().tolist()
    mesh.userface = faces.ravel().tolist()
    mesh.usernormal = normals.ravel().tolist()
    body = spec.worldbody.add_body(name=RING_BODY, mocap=True, pos=[0.0, 0.0, 0.05])
    body.add_geom(
        name="ring_torus",
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname="ring_mesh",
        rgba=list(sc.ring_rgba),
        group=GROUP_RING,
        contype=0,
        conaffinity=0,
    )
    x_end = ring.major_radius + ring.handle_length
    add_geom(
        body,
        GeomSpec(
            "ring_handle",
            "capsule",
            (ring.handle_radius,),
            fromto=(ring.major_radius, 0, 0, x_end, 0, 0),
            rgba=sc.handle_rgba,
        ),
        GROUP_RING,
    )
    tip = psm1_tip_in_ring(ring, ins)
    geoms = _instrument_geoms("psm1", float(tip[0]), 0.0, 2.0 * ring.handle_radius, ins)
    for g in geoms:
        add_geom(body, g, GROUP_INSTRUMENT)
    body.add_site(name=TIP_SITES[0], pos=tip.tolist(), size=[1e-3, 0, 0], group=5)
