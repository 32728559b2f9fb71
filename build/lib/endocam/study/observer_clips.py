"""Clips with known touches and known views, to validate the automatic observer on its own.

A clip holds the ring on the default wire at one arc length and pushes it across the wire and
back, ``touches`` times, so the wire meets the inner rim once per push. It carries the study's
conditions (:class:`ClipSpec`):

- **angle noise** between the ring's normal and the wire's tangent, as the study's noisy
  trajectories have (``ANGLE_NOISE_DEG`` = 10–30°, seeded): the ring is turned by that angle
  about the push direction, plus up to ``CROSS_TILT_DEG`` about the other in-plane axis;
- **pushes in several directions** across the wire: the push direction ``u`` is drawn in the
  plane perpendicular to the wire's tangent (any angle, seeded) and the pushes alternate
  between ``+u`` and ``−u``; each push goes ``PUSH_PAST`` beyond contact (found by bisection on
  the exact clearance), so every push is one true touch whatever the noise;
- **views sampled like the study's cameras** (``VIEW_KINDS``): ``head-on`` along the ring's
  (noisy) normal from 35–50 mm (the orientation camera), ``oblique`` 30–50° off it from
  40–60 mm (the centring camera), ``distant`` 40–60° off it from 110–130 mm (the fixed
  camera's framing, ~3.3 px/mm);
- **a slowly moving camera**: the view angle sways ±``SWAY_DEG`` and the distance
  ±``SWAY_DISTANCE`` (relative) once per ``SWAY_PERIOD_S``, with a seeded roll about the
  optical axis and the ring off the image centre.

**Why an ideal observer could count every touch**: the camera only ever turns about the push
direction ``u``, so ``u`` (the direction in which the gap between the wire and the rim opens and
closes) stays perpendicular to the optical axis in every frame; and the wire's tangent is
perpendicular to ``u`` too (``CROSS_TILT_DEG`` aside), so the wire's own silhouette runs across
the gap, never along it, and cannot hide it.

The true touches come from the exact clearance (:func:`endocam.task.touches.clearances`)
sampled every millisecond. The validation set (:func:`validation_specs`) is split: the tuning
clips (``TUNING_ARC_FRACTIONS``, noise seeds from ``TUNING_SEED``) were looked at while the
observer was set up; the held-out clips sit at other bends (``TEST_ARC_FRACTIONS``) and draw
their noise from another seed (``TEST_SEED``).

``python -m endocam.study.observer_clips [--cache DIR]`` renders the validation set (or reuses
the MP4s cached in ``DIR``), encodes each clip as H.264 (as the study videos are), runs the
observer on the decoded video and prints its precision and recall per clip and pooled per view.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.camera import StereoCamera
from endocam.config import CameraConfig
from endocam.geometry import FloatArray, make_pose
from endocam.study.observer import ColourKeys, Match, match_events, observe_video
from endocam.study.visibility import GAP_SEEN
from endocam.task.config import TaskConfig, WireConfig
from endocam.task.trajectory import ideal_ring_rotations
from endocam.task.wire import Wire

TUNING_ARC_FRACTIONS = (0.3, 0.55)  # unitless, bends looked at while setting the observer up
TEST_ARC_FRACTIONS = (0.2, 0.4, 0.65, 0.8)  # held-out bends, never tuned on
TUNING_SEED = 11  # noise seeds of the tuning clips come from default_rng(TUNING_SEED)
TEST_SEED = 12_011  # ... and of the held-out clips from default_rng(TEST_SEED)
CLIPS_PER_CELL = 2  # clips per (bend, view kind)
VIEW_KINDS = ("head-on", "oblique", "distant")
PUSH_PERIOD_S = 1.2  # s, one push and return
LEAD_IN_S = 1.0  # s, the ring rests clear of the wire before the first push (the view settles)
PUSH_PAST = 0.6e-3  # m, how far each push goes beyond contact (clearance −PUSH_PAST at its peak)
PUSH_SEARCH_MAX = 8.0e-3  # m, the push depth bisection's upper bound (beyond any free play)
PUSH_SEARCH_TOL = 1.0e-6  # m, the bisection's tolerance
ANGLE_NOISE_DEG = (10.0, 30.0)  # deg, ring normal vs wire tangent (the study's angle noise)
CROSS_TILT_DEG = 5.0  # deg, largest tilt about the in-plane axis across the push direction
VIEW_ANGLE_DEG = {"head-on": (0.0, 10.0), "oblique": (30.0, 50.0), "distant": (40.0, 60.0)}
VIEW_DISTANCE = {"head-on": (0.035, 0.05), "oblique": (0.04, 0.06), "distant": (0.11, 0.13)}  # m
SWAY_DEG = 5.0  # deg, amplitude of the camera's slow swing about the push direction
SWAY_DISTANCE = 0.1  # unitless, relative amplitude of the camera's slow in/out motion
SWAY_PERIOD_S = 4.0  # s, period of the camera's slow motion
ROLL_DEG = 20.0  # deg, largest roll of the camera about its optical axis
AIM_OFFSET = 2.0e-3  # m, largest offset of the aim point from the ring's centre
BOX_MARGIN = 0.01  # m, the camera keeps this far inside the box's walls, board and top
BOX_STEP = 0.95  # unitless, distance factor per step when a view would leave the box
GAP_SEEN_DT = 5e-3  # s, time step searching for the GAP_SEEN instant (observability's is 1 ms)
RAY_CAMERA_PX = (64, 48)  # px, the (unused) image of the scene that only casts rays
MAX_DRAWS = 50  # draws per clip before giving up
TRUTH_DT = 1e-3  # s, sampling of the true clearance
CLIP_TOUCHES = 4  # pushes per validation clip
CLIP_FPS = 30.0  # frames/s of the validation clips (the study's video rate)


@dataclass(frozen=True)
class ClipSpec:
    """Everything that defines a validation clip (angles in deg, lengths in m).

    Attributes
    ----------
    arc_fraction : float
        Where on the wire the ring sits (fraction of its length).
    view : str
        One of ``VIEW_KINDS`` (for tables; the numbers below define the view).
    view_deg : float
        Optical axis vs the ring's normal at rest, turned about the push direction, deg.
    distance : float
        Camera to aim point, m.
    tilt_deg : float
        Ring normal vs wire tangent about the push direction, deg (signed).
    cross_tilt_deg : float
        Tilt about the in-plane axis across the push direction, deg (signed).
    push_angle_deg : float
        Push direction in the plane normal to the wire's tangent, from the ring's ``y``, deg.
    roll_deg : float
        Camera roll about its optical axis, deg.
    aim : tuple of float
        Aim point offset from the ring's centre in the image plane (right, down), m.
    sway_phase : float
        Phase of the camera's slow motion, rad.
    moving : bool
        Whether the camera sways (``SWAY_DEG``, ``SWAY_DISTANCE``).
    """

    arc_fraction: float
    view: str = "head-on"
    view_deg: float = 0.0
    distance: float = 0.05
    tilt_deg: float = 0.0
    cross_tilt_deg: float = 0.0
    push_angle_deg: float = 0.0
    roll_deg: float = 0.0
    aim: tuple[float, float] = (0.0, 0.0)
    sway_phase: float = 0.0
    moving: bool = False

    @property
    def name(self) -> str:
        """A file-name-safe label."""
        return (
            f"{self.view}-{self.arc_fraction:.2f}-v{self.view_deg:+.0f}-t{self.tilt_deg:+.0f}"
            f"-p{self.push_angle_deg:.0f}-d{1e3 * self.distance:.0f}"
        )


def draw_spec(rng: np.random.Generator, arc_fraction: float, view: str) -> ClipSpec:
    """A clip of ``view`` kind at ``arc_fraction`` with its noise drawn from ``rng``."""
    lo, hi = ANGLE_NOISE_DEG
    a_lo, a_hi = VIEW_ANGLE_DEG[view]
    d_lo, d_hi = VIEW_DISTANCE[view]
    return ClipSpec(
        arc_fraction=arc_fraction,
        view=view,
        view_deg=float(rng.uniform(a_lo, a_hi) * rng.choice([-1.0, 1.0])),
        distance=float(rng.uniform(d_lo, d_hi)),
        tilt_deg=float(rng.uniform(lo, hi) * rng.choice([-1.0, 1.0])),
        cross_tilt_deg=float(rng.uniform(-CROSS_TILT_DEG, CROSS_TILT_DEG)),
        push_angle_deg=float(rng.uniform(0.0, 360.0)),
        roll_deg=float(rng.uniform(-ROLL_DEG, ROLL_DEG)),
        aim=(
            float(rng.uniform(-AIM_OFFSET, AIM_OFFSET)),
            float(rng.uniform(-AIM_OFFSET, AIM_OFFSET)),
        ),
        sway_phase=float(rng.uniform(0.0, 2.0 * math.pi)),
        moving=True,
    )


def _camera_in_box(task: TaskConfig, spec: ClipSpec) -> bool:
    """Whether the clip's camera (at every sway extreme) is inside the training box."""
    t = np.linspace(0.0, SWAY_PERIOD_S, 9)
    p = camera_poses(task, spec, t)[:, :3, 3]
    half = 0.5 * np.asarray(task.scene.board_size[:2]) - BOX_MARGIN
    return bool(
        np.all(np.abs(p[:, :2]) <= half)
        and np.all((p[:, 2] > BOX_MARGIN) & (p[:, 2] < task.scene.backdrop_height - BOX_MARGIN))
    )


def from_above(task: TaskConfig, spec: ClipSpec) -> ClipSpec:
    """``spec`` with the sign of its view angle that keeps the camera inside the training box.

    As the study's cameras are; of two that fit, the higher (looking down at the board). A view
    that fits neither way is moved nearer the ring by ``BOX_STEP`` until it does.
    """
    while True:
        options = [spec, replace(spec, view_deg=-spec.view_deg)]
        inside = [o for o in options if _camera_in_box(task, o)]
        if inside:
            return max(inside, key=lambda o: camera_poses(task, o, np.zeros(1))[0, 2, 3])
        spec = replace(spec, distance=spec.distance * BOX_STEP)


def gap_visible(task: TaskConfig, spec: ClipSpec, touches: int = CLIP_TOUCHES) -> bool:
    """Whether the closing gap is in sight before every push's touch (MuJoCo ray casts).

    For each push, at the first instant its clearance falls to ``GAP_SEEN`` (the gap still
    open), the closest-approach point between the wire and the rim (in the gap) must be
    unoccluded from the left eye at the camera's pose then: nothing (not the wire's near part,
    not the rim, not an instrument) hides the place where the gap closes.
    """
    from endocam.config import CameraConfig
    from endocam.sim.render import WireChaserScene
    from endocam.task.touches import clearances

    t = np.arange(0.0, LEAD_IN_S + touches * PUSH_PERIOD_S, GAP_SEEN_DT)
    depths = push_depths(task, spec)
    rings = ring_poses(task, spec, t, depths)
    c, p = clearances(rings, clip_wire(task.wire), task.ring)
    cams = camera_poses(task, spec, t)
    push = np.floor(np.maximum(t - LEAD_IN_S, 0.0) / PUSH_PERIOD_S).astype(int)
    rays_only = CameraConfig(width=RAY_CAMERA_PX[0], height=RAY_CAMERA_PX[1]).stereo()
    with WireChaserScene(task, rays_only) as scene:
        for k in range(touches):
            idx = np.flatnonzero((push == k) & (t > LEAD_IN_S) & (c <= GAP_SEEN))
            if idx.size == 0:
                return False
            i = int(idx[0])
            scene.set_ring_pose(rings[i])
            scene.set_camera_pose(cams[i])
            if not scene.ray_visible(p[i], cams[i], "left"):
                return False
    return True


@functools.lru_cache(maxsize=4)
def clip_wire(config: WireConfig) -> Wire:
    """The wire of ``config``, built once: the clips' geometry asks for it at every pose."""
    return Wire(config)


@functools.cache
def _default_specs(held_out: bool) -> tuple[ClipSpec, ...]:
    """:func:`validation_specs` of the default task, drawn once per process."""
    return tuple(validation_specs(held_out, TaskConfig()))


def validation_specs(held_out: bool, task: TaskConfig | None = None) -> list[ClipSpec]:
    """The tuning (``held_out=False``) or held-out clip specs, noise seeded per set.

    Each is drawn (:func:`draw_spec`, :func:`from_above`) until its gap is in sight before
    every touch (:func:`gap_visible`), at most ``MAX_DRAWS`` times.
    """
    if task is None:
        return list(_default_specs(held_out))
    return list(iter_validation_specs(held_out, task))


def iter_validation_specs(held_out: bool, task: TaskConfig) -> Iterator[ClipSpec]:
    """:func:`validation_specs` one at a time, each drawn when asked for (bend, view, clip).

    The first few cost a few ray-cast scenes, not the whole set's (a test of a few clips).
    """
    rng = np.random.default_rng(TEST_SEED if held_out else TUNING_SEED)
    arcs = TEST_ARC_FRACTIONS if held_out else TUNING_ARC_FRACTIONS
    for arc in arcs:
        for view in VIEW_KINDS:
            for _ in range(CLIPS_PER_CELL):
                for _ in range(MAX_DRAWS):
                    spec = from_above(task, draw_spec(rng, arc, view))
                    if gap_visible(task, spec):
                        break
                else:  # pragma: no cover - no default bend needs it
                    raise RuntimeError(f"no view of {view} at {arc} shows the gap")
                yield spec


@dataclass(frozen=True)
class Clip:
    """A validation clip.

    Attributes
    ----------
    frames : (F, H, W, 3) uint8
        Left-eye RGB frames.
    fps : float
        Frames/s.
    true_events : list of (t_start, t_end)
        Touch intervals, s.
    spec : ClipSpec
    """

    frames: np.ndarray
    fps: float
    true_events: list[tuple[float, float]]
    spec: ClipSpec


# ------------------------------------------------------------------ geometry of a clip
def _rest_frame(task: TaskConfig, spec: ClipSpec) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The ring's noisy rest rotation (3, 3), its centre (3,), m, and the push direction (3,)."""
    wire = clip_wire(task.wire)
    s = spec.arc_fraction * wire.length
    R0 = ideal_ring_rotations(wire, np.array([s]))[0]
    centre = wire.points(np.array([s]))[0]
    psi = math.radians(spec.push_angle_deg)
    u = math.cos(psi) * R0[:, 1] + math.sin(psi) * R0[:, 0]  # ⊥ the wire's tangent R0[:, 2]
    across = np.cross(R0[:, 2], u)  # in-plane, ⊥ u
    turn = Rotation.from_rotvec(math.radians(spec.tilt_deg) * u) * Rotation.from_rotvec(
        math.radians(spec.cross_tilt_deg) * across
    )
    return turn.as_matrix() @ R0, centre, u


def push_depths(task: TaskConfig, spec: ClipSpec) -> tuple[float, float]:
    """Offsets (m) along ``+u`` and ``−u`` at which the clearance is ``−PUSH_PAST`` (bisection)."""
    from endocam.task.touches import clearances

    R, centre, u = _rest_frame(task, spec)
    wire = clip_wire(task.wire)
    out = []
    for sign in (1.0, -1.0):
        lo, hi = 0.0, PUSH_SEARCH_MAX
        while hi - lo > PUSH_SEARCH_TOL:
            mid = 0.5 * (lo + hi)
            c, _ = clearances(make_pose(R, centre + sign * mid * u)[None], wire, task.ring)
            lo, hi = (mid, hi) if c[0] > -PUSH_PAST else (lo, mid)
        out.append(0.5 * (lo + hi))
    return out[0], out[1]


def ring_poses(
    task: TaskConfig, spec: ClipSpec, t: FloatArray, depths: tuple[float, float] | None = None
) -> FloatArray:
    """(N, 4, 4) ring poses at times ``t`` (N,), s: pushed across the wire and back each period.

    After ``LEAD_IN_S`` at rest, push ``k`` (0-based) goes along ``+u`` (even ``k``) or ``−u``
    (odd) to ``depths`` (m, default :func:`push_depths`) and back within ``PUSH_PERIOD_S``.
    """
    R, centre, u = _rest_frame(task, spec)
    d_plus, d_minus = push_depths(task, spec) if depths is None else depths
    tt = np.maximum(np.asarray(t, dtype=float) - LEAD_IN_S, 0.0)
    k = np.floor(tt / PUSH_PERIOD_S)
    phase = tt / PUSH_PERIOD_S - k
    sign = np.where(k % 2 == 0, 1.0, -1.0)
    depth = np.where(sign > 0, d_plus, -d_minus)
    offset = 0.5 * depth * (1.0 - np.cos(2.0 * math.pi * phase))
    T = np.repeat(make_pose(R, centre)[None], len(tt), axis=0)
    T[:, :3, 3] = centre + offset[:, None] * u[None]
    return T


def camera_poses(task: TaskConfig, spec: ClipSpec, t: FloatArray) -> FloatArray:
    """(N, 4, 4) camera (optical frame) poses at times ``t`` (N,), s.

    The camera looks at the resting ring's centre (offset by ``spec.aim`` in the image plane)
    from ``spec.distance``, ``spec.view_deg`` off the ring's normal, always turned about the push
    direction ``u`` (so ``u`` stays in the image plane); the ring's handle is up in the image
    before the roll. A moving camera sways about ``u`` and in/out slowly.
    """
    R, centre, u = _rest_frame(task, spec)
    normal = R[:, 2] - (R[:, 2] @ u) * u  # the ring's normal, in the plane ⊥ u
    normal /= np.linalg.norm(normal)
    t = np.asarray(t, dtype=float)
    wave = np.sin(2.0 * math.pi * t / SWAY_PERIOD_S + spec.sway_phase) if spec.moving else 0 * t
    angle = np.radians(spec.view_deg + SWAY_DEG * wave)
    dist = spec.distance * (1.0 + SWAY_DISTANCE * np.cos(2.0 * math.pi * t / SWAY_PERIOD_S))
    if not spec.moving:
        dist = np.full_like(t, spec.distance)
    side = np.cross(u, normal)
    out = np.empty((t.size, 4, 4))
    roll = Rotation.from_rotvec(np.zeros(3))
    for i, (a, d) in enumerate(zip(angle, dist, strict=True)):
        toward = math.cos(a) * normal + math.sin(a) * side  # from the ring to the camera, ⊥ u
        z = -toward
        up = R[:, 0] - (R[:, 0] @ z) * z  # the handle's direction in the image plane
        if np.linalg.norm(up) < 1e-6:  # pragma: no cover - the handle along the line of sight
            up = u.copy()
        y = -up / np.linalg.norm(up)  # image down = away from the handle
        x = np.cross(y, z)
        roll = Rotation.from_rotvec(math.radians(spec.roll_deg) * z)
        Rc = roll.as_matrix() @ np.column_stack([x, y, z])
        aim = centre + spec.aim[0] * Rc[:, 0] + spec.aim[1] * Rc[:, 1]
        out[i] = make_pose(Rc, aim + d * toward)
    return out


def true_touches(
    task: TaskConfig,
    spec: ClipSpec,
    duration: float,
    depths: tuple[float, float] | None = None,
) -> list[tuple[float, float]]:
    """Touch intervals (s) of the clip's motion, from the exact clearance every ``TRUTH_DT``."""
    from endocam.task.touches import clearances

    t = np.arange(0.0, duration + 0.5 * TRUTH_DT, TRUTH_DT)
    c, _ = clearances(ring_poses(task, spec, t, depths), clip_wire(task.wire), task.ring)
    inside = c <= 0.0
    edges = np.flatnonzero(np.diff(inside.astype(int)))
    events, start = [], None
    if inside[0]:
        start = 0.0
    for k in edges:
        if inside[k + 1]:
            start = float(t[k + 1])
        elif start is not None:
            events.append((start, float(t[k])))
            start = None
    if start is not None:
        events.append((start, float(t[-1])))
    return events


def render_clip(
    task: TaskConfig,
    camera: StereoCamera,
    spec: ClipSpec,
    touches: int = CLIP_TOUCHES,
    fps: float = CLIP_FPS,
    depth_scale: float = 1.0,
) -> Clip:
    """Render a clip of ``touches`` pushes at ``fps`` frames/s.

    Each push goes ``depth_scale`` × its depth from :func:`push_depths` (m); scaled below the
    free play, it touches nothing.
    """
    from endocam.sim.render import WireChaserScene

    d_plus, d_minus = push_depths(task, spec)
    depths = (depth_scale * d_plus, depth_scale * d_minus)
    duration = LEAD_IN_S + touches * PUSH_PERIOD_S
    t = np.arange(math.floor(duration * fps) + 1) / fps
    frames = []
    with WireChaserScene(task, camera) as scene:
        for T_ring, T_cam in zip(
            ring_poses(task, spec, t, depths), camera_poses(task, spec, t), strict=True
        ):
            scene.set_ring_pose(T_ring)
            scene.set_camera_pose(T_cam)
            frames.append(scene.render("left"))
    truth = true_touches(task, spec, duration, depths)
    return Clip(np.stack(frames), fps, truth, spec)


def write_clip(clip: Clip, folder: Path) -> Path:
    """Encode ``clip`` as H.264 into ``folder``: ``<name>.mp4`` and ``<name>.json`` (the truth)."""
    from endocam.runner.outputs import video_writer

    path = folder / f"clip-{clip.spec.name}.mp4"
    h, w = clip.frames.shape[1:3]
    writer = video_writer(path, w, h, clip.fps)
    try:
        for frame in clip.frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()
    meta = {"spec": asdict(clip.spec), "fps": clip.fps, "true_events": clip.true_events}
    path.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n", "utf-8")
    return path


def score_video(path: Path, keys: ColourKeys) -> Match:
    """Observe an encoded clip (``write_clip``) and score it against its truth."""
    meta = json.loads(path.with_suffix(".json").read_text("utf-8"))
    obs = observe_video(path, keys)
    seen = [(s.t_start, s.t_end) for s in obs.touches]
    true = [tuple(e) for e in meta["true_events"]]
    return match_events(seen, true, 1.0 / float(meta["fps"]))


def observe_clip(clip: Clip, keys: ColourKeys, folder: Path) -> Match:
    """Encode ``clip`` as H.264, observe the decoded video, score it against the truth."""
    return score_video(write_clip(clip, folder), keys)


def pooled(matches: list[Match]) -> Match:
    """The sum of several clips' matches."""
    return Match(*(sum(getattr(m, f) for m in matches) for f in ("true_positives", "seen", "true")))


def main(argv: list[str] | None = None) -> int:  # pragma: no cover - the documented command
    """Print the observer's precision and recall per clip (640×480, 30 fps) and pooled per view."""
    parser = argparse.ArgumentParser(prog="python -m endocam.study.observer_clips")
    parser.add_argument("--cache", type=Path, help="keep (and reuse) the encoded clips here")
    parser.add_argument("--set", choices=("tuning", "held-out", "both"), default="both")
    args = parser.parse_args(argv)
    task = TaskConfig()
    camera = CameraConfig().stereo()
    keys = ColourKeys.from_scene(task.scene)
    sets = [("tuning", False), ("held-out", True)]
    sets = [s for s in sets if args.set in ("both", s[0])]
    print("| set | clip | true | seen | precision | recall |")
    print("|---|---|---|---|---|---|")
    results: dict[tuple[str, str], list[Match]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.cache if args.cache is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name, held_out in sets:
            for spec in validation_specs(held_out):
                path = folder / f"clip-{spec.name}.mp4"
                if not (path.is_file() and path.with_suffix(".json").is_file()):
                    path = write_clip(render_clip(task, camera, spec), folder)
                m = score_video(path, keys)
                results.setdefault((name, spec.view), []).append(m)
                print(
                    f"| {name} | {spec.name} | {m.true} | {m.seen} | {m.precision:.2f} | "
                    f"{m.recall:.2f} |",
                    flush=True,
                )
    print("\n| set | view | true touches | seen | precision | recall |")
    print("|---|---|---|---|---|---|")
    for (name, view), ms in results.items():
        m = pooled(ms)
        print(f"| {name} | {view} | {m.true} | {m.seen} | {m.precision:.2f} | {m.recall:.2f} |")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
