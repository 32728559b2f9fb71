"""Clips with known touches and known views, to validate the automatic observer on its own.

A clip holds the ring on the default wire at one arc length and pushes it sideways (along the
ring's y axis, across the wire) and back, ``touches`` times, so the wire meets the inner rim once
per push. The camera is fixed at the working distance on a chosen view: ``view_deg`` is the angle
between the optical axis and the ring's normal, turned about the ring's y axis (the push
direction), so the closing gap stays across the line of sight (0° looks through the ring along
the wire, as the orientation camera does; 60° sees the ring obliquely, as the fixed camera often
does). The ring rests clear of the wire for ``LEAD_IN_S`` first (an assessor's view settles).
The true touches come from the exact clearance (:func:`endocam.task.touches.clearances`) sampled
every millisecond.

The validation set is split by where the ring sits on the wire: the clips at
``TUNING_ARC_FRACTIONS`` were looked at while the observer was set up; those at
``TEST_ARC_FRACTIONS`` (other bends of the wire, so the wire leaves the ring differently in the
image) were not.

``python -m endocam.study.observer_clips`` renders the validation set, encodes each clip as
H.264 (as the study videos are), runs the observer on the decoded video and prints its precision
and recall per clip.
"""

from __future__ import annotations

import math
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from endocam.camera import StereoCamera
from endocam.config import CameraConfig
from endocam.geometry import FloatArray, make_pose
from endocam.study.observer import ColourKeys, Match, match_events, observe_video
from endocam.task.config import TaskConfig
from endocam.task.trajectory import ideal_ring_rotations
from endocam.task.wire import Wire

CLIP_ARC_FRACTION = 0.3  # unitless, where on the wire the clip's ring sits (a gentle stretch)
TUNING_ARC_FRACTIONS = (CLIP_ARC_FRACTION,)  # clips looked at while setting the observer
TEST_ARC_FRACTIONS = (0.2, 0.4, 0.5, 0.65, 0.8)  # held-out clips: other bends, never tuned on
PUSH_PERIOD_S = 1.2  # s, one push and return
LEAD_IN_S = 1.0  # s, the ring rests clear of the wire before the first push (the view settles)
PUSH_DEPTH = 3.6e-3  # m, largest sideways offset: ~0.6 mm past contact on the default ring
CLIP_DISTANCE = 0.05  # m, camera to ring centre (the controller's working distance d_f)
TRUTH_DT = 1e-3  # s, sampling of the true clearance
VALIDATION_VIEWS_DEG = (0.0, 30.0, 45.0, 60.0)  # views of the validation set


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
    view_deg : float
        Optical axis vs ring normal, deg.
    arc_fraction : float
        Where on the wire the ring sits (fraction of the wire's length).
    """

    frames: np.ndarray
    fps: float
    true_events: list[tuple[float, float]]
    view_deg: float
    arc_fraction: float = CLIP_ARC_FRACTION


def ring_poses(
    task: TaskConfig,
    t: FloatArray,
    push_depth: float = PUSH_DEPTH,
    arc_fraction: float = CLIP_ARC_FRACTION,
) -> FloatArray:
    """(N, 4, 4) ring poses at times ``t`` (N,), s: pushed sideways and back each period.

    After ``LEAD_IN_S`` at rest, the push (along the ring's y axis, across the wire) reaches
    ``push_depth`` (m) once every ``PUSH_PERIOD_S``; the ring sits at ``arc_fraction`` of the
    wire's length.
    """
    wire = Wire(task.wire)
    s = arc_fraction * wire.length
    R = ideal_ring_rotations(wire, np.array([s]))[0]
    centre = wire.points(np.array([s]))[0]
    phase = np.maximum(np.asarray(t) - LEAD_IN_S, 0.0) / PUSH_PERIOD_S
    offset = 0.5 * push_depth * (1.0 - np.cos(2.0 * math.pi * phase))
    T = np.repeat(make_pose(R, centre)[None], len(t), axis=0)
    T[:, :3, 3] = centre + offset[:, None] * R[:, 1][None]
    return T


def camera_pose(
    task: TaskConfig, view_deg: float, arc_fraction: float = CLIP_ARC_FRACTION
) -> FloatArray:
    """(4, 4) camera (optical frame) looking at the resting ring from ``CLIP_DISTANCE``.

    The view is ``view_deg`` off the ring's normal, turned about the ring's y axis (the push
    direction); the ring's handle is up in the image.
    """
    T_ring = ring_poses(task, np.zeros(1), arc_fraction=arc_fraction)[0]
    R = T_ring[:3, :3]
    a = math.radians(view_deg)
    toward = math.cos(a) * R[:, 2] + math.sin(a) * R[:, 0]  # from the ring towards the camera
    z = -toward
    y = -R[:, 0] + (R[:, 0] @ z) * z  # image down = away from the handle
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return make_pose(np.column_stack([x, y, z]), T_ring[:3, 3] + CLIP_DISTANCE * toward)


def true_touches(
    task: TaskConfig,
    duration: float,
    push_depth: float = PUSH_DEPTH,
    arc_fraction: float = CLIP_ARC_FRACTION,
) -> list[tuple[float, float]]:
    """Touch intervals (s) of the clip's motion, from the exact clearance every ``TRUTH_DT``."""
    from endocam.task.touches import clearances

    t = np.arange(0.0, duration + 0.5 * TRUTH_DT, TRUTH_DT)
    c, _ = clearances(ring_poses(task, t, push_depth, arc_fraction), Wire(task.wire), task.ring)
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
    view_deg: float,
    touches: int,
    fps: float,
    push_depth: float = PUSH_DEPTH,
    arc_fraction: float = CLIP_ARC_FRACTION,
) -> Clip:
    """Render a clip of ``touches`` pushes seen ``view_deg`` off the ring's normal.

    Each push reaches ``push_depth`` (m); one shallower than the ring's free play touches nothing.
    The ring sits at ``arc_fraction`` of the wire's length.
    """
    from endocam.sim.render import WireChaserScene

    duration = LEAD_IN_S + touches * PUSH_PERIOD_S
    t = np.arange(math.floor(duration * fps) + 1) / fps
    frames = []
    with WireChaserScene(task, camera) as scene:
        scene.set_camera_pose(camera_pose(task, view_deg, arc_fraction))
        for T in ring_poses(task, t, push_depth, arc_fraction):
            scene.set_ring_pose(T)
            frames.append(scene.render("left"))
    truth = true_touches(task, duration, push_depth, arc_fraction)
    return Clip(np.stack(frames), fps, truth, view_deg, arc_fraction)


def observe_clip(clip: Clip, keys: ColourKeys, folder: Path) -> Match:
    """Encode ``clip`` as H.264, observe the decoded video, score it against the truth."""
    from endocam.runner.outputs import video_writer

    path = folder / f"clip-{clip.view_deg:.0f}-{clip.arc_fraction:.2f}.mp4"
    h, w = clip.frames.shape[1:3]
    writer = video_writer(path, w, h, clip.fps)
    try:
        for frame in clip.frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()
    obs = observe_video(path, keys)
    seen = [(s.t_start, s.t_end) for s in obs.touches]
    return match_events(seen, clip.true_events, 1.0 / clip.fps)


def main() -> int:  # pragma: no cover - the command that measured the documented numbers
    """Print the observer's precision and recall per clip (640×480, 30 fps) and pooled per view."""
    task = TaskConfig()
    camera = CameraConfig().stereo()
    keys = ColourKeys.from_scene(task.scene)
    print("| set | arc fraction | view (deg) | true touches | seen | precision | recall |")
    print("|---|---|---|---|---|---|---|")
    sets = [("tuning", a) for a in TUNING_ARC_FRACTIONS] + [("test", a) for a in TEST_ARC_FRACTIONS]
    pooled: dict[tuple[str, float], list[Match]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, arc in sets:
            for view in VALIDATION_VIEWS_DEG:
                clip = render_clip(task, camera, view, touches=5, fps=30.0, arc_fraction=arc)
                m = observe_clip(clip, keys, Path(tmp))
                pooled.setdefault((name, view), []).append(m)
                print(
                    f"| {name} | {arc:.2f} | {view:.0f} | {m.true} | {m.seen} | "
                    f"{m.precision:.2f} | {m.recall:.2f} |",
                    flush=True,
                )
    print("\n| set | view (deg) | true touches | seen | precision | recall |")
    print("|---|---|---|---|---|---|")
    for (name, view), ms in pooled.items():
        m = Match(*(sum(getattr(k, f) for k in ms) for f in ("true_positives", "seen", "true")))
        print(f"| {name} | {view:.0f} | {m.true} | {m.seen} | {m.precision:.2f} | {m.recall:.2f} |")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
