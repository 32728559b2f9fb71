r"""Objective touch observability: how well a viewer could see each ground-truth touch.

The paper could only ask assessors; the simulator can measure what each study video showed of
every touch. For each ground-truth touch event (:class:`~endocam.task.touches.TouchEvent`) of a
study video, at the touch's **onset** ``t_start`` — the instant the ring meets the wire — we
compute, for the video's (left) eye:

- ``in_image``: the contact point projects inside the image (in front of the eye, ``0 ≤ u < W``,
  ``0 ≤ v < H``);
- ``unoccluded``: a MuJoCo ray cast from the eye to the contact point
  (:meth:`~endocam.sim.render.WireChaserScene.ray_visible`) through *every* geom — board, posts,
  wire, ring, handle, instruments, arm links — reaches it, allowing the documented
  ``DEFAULT_RAY_TOLERANCE`` (2 mm, a tube diameter) in front of it, so the contact is not hidden
  by the two 1 mm tubes it sits on, only by something else (e.g. the far side of the ring, the
  handle, an instrument or the board);
- ``visible`` = ``in_image and unoccluded``;
- ``view_angle_deg``: the angle between the optical axis and the ring normal (ring z), folded to
  0–90° (the normal's sign is arbitrary; :func:`endocam.metrics.orientation_error`): 0° looks
  straight through the ring, 90° sees it edge-on;
- ``px_per_mm``: image scale at the contact's depth, :math:`f / z \cdot 10^{-3}` px per mm of a
  length perpendicular to the line of sight;
- ``gap_px_per_mm``: how many pixels one millimetre of ring–wire gap, opened along the contact
  normal :math:`\hat u` (wire centre → ring core circle), spans in the image:
  :math:`\lVert J_\pi(p)\,\hat u\rVert \cdot 10^{-3}` with :math:`J_\pi` the 2×3 Jacobian of the
  pinhole projection at the contact point. Just before and after a touch the viewer sees a gap of
  about ``clearance × gap_px_per_mm``; it is 0 when the gap opens along the line of sight (ring
  in front of the wire: touching and passing in front look the same) and about ``px_per_mm``
  when it opens across the view.

Why the onset and not the deepest sample: the ring is kinematic, so during a touch it may pass
through the wire (clearances down to −2 mm, i.e. the wire's centre line crosses the ring's core
circle); the deepest contact point is then buried in both tubes and the contact normal is
undefined. At the onset the contact point lies on both surfaces and the normal is well defined.
The whole event is also **sampled at the video's frames**: ``frames`` counts the frames whose
time falls inside ``[t_start, t_end]`` (a touch shorter than a frame interval may show in none),
and ``visible_frames`` those in which the contact point of that instant is visible (same test).

Beside the onset, each touch's **closing gap** (:mod:`endocam.study.visibility`): the gap at
0.5 mm just before the onset, from the left eye, the right eye and either, its size in pixels
and ``resolved`` (in sight and at least 2 px): the measure the report leads with.

:func:`observe_contact` works on one pose pair and a scene; :func:`summarize` condenses records
per condition (shares with seed-level intervals, medians) into what ``observability.json`` and
the study report show.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from endocam.camera import Eye
from endocam.geometry import as_pose, as_vector3
from endocam.metrics import orientation_error
from endocam.study.visibility import (
    ClosingGap,
    ShareCI,
    closing_gap,
    control_step,
    hider_kind,
    in_image,
    pixel_scales,
    share_ci,
)
from endocam.task.touches import contact_normal

if TYPE_CHECKING:
    from endocam.runner.episode import EpisodeResult
    from endocam.sim.render import WireChaserScene

OBSERVABILITY_JSON = "observability.json"
OBSERVABILITY_CSV = "observability.csv"
MM_PER_M = 1e3  # mm / m
_EPS = 1e-12  # m, below this a direction is undefined


# ---------------------------------------------------------------------------- one contact
@dataclass(frozen=True)
class ContactView:
    """What one eye sees of one contact point (see the module docstring).

    Attributes
    ----------
    in_image, unoccluded : bool
        Inside the image; reached by the ray cast.
    view_angle_deg : float
        Optical axis vs ring normal, deg in [0, 90].
    px_per_mm : float
        Image scale at the contact depth, px/mm (NaN behind the eye).
    gap_px_per_mm : float
        Image length of 1 mm along the contact normal, px/mm (NaN behind the eye or when the
        normal is undefined).
    """

    in_image: bool
    unoccluded: bool
    view_angle_deg: float
    px_per_mm: float
    gap_px_per_mm: float

    @property
    def visible(self) -> bool:
        """Inside the image and not occluded."""
        return self.in_image and self.unoccluded


def observe_contact(
    scene: WireChaserScene,
    T_world_ring: ArrayLike,
    T_world_cam: ArrayLike,
    p_world_contact: ArrayLike,
    eye: Eye = "left",
) -> ContactView:
    """Place the ring and camera in ``scene`` and measure what ``eye`` sees of a contact point.

    Parameters
    ----------
    scene : WireChaserScene
        The rendered world (its ring and camera poses are changed).
    T_world_ring : (4, 4)
        Ring pose, m.
    T_world_cam : (4, 4)
        Camera pose (optical frame), m.
    p_world_contact : (3,)
        Contact point in world, m.
    eye : {"left", "right"}

    Returns
    -------
    ContactView
    """
    T_ring = as_pose(T_world_ring, "T_world_ring")
    T_cam = as_pose(T_world_cam, "T_world_cam")
    p = as_vector3(p_world_contact, "p_world_contact")
    scene.set_ring_pose(T_ring)
    scene.set_camera_pose(T_cam)
    camera = scene.camera
    try:
        u = contact_normal(p, T_ring, scene.task_cfg.ring.major_radius)
        px_per_m, gap_px_per_m = pixel_scales(camera, T_cam, p, u, eye)
    except ValueError:
        px_per_m, _ = pixel_scales(camera, T_cam, p, T_cam[:3, 0], eye)
        gap_px_per_m = math.nan
    return ContactView(
        in_image=in_image(camera, T_cam, p, eye),
        unoccluded=scene.ray_visible(p, T_cam, eye),
        view_angle_deg=math.degrees(float(orientation_error(T_cam, T_ring[:3, 2])[0])),
        px_per_mm=px_per_m / MM_PER_M,
        gap_px_per_mm=gap_px_per_m / MM_PER_M,
    )


# ------------------------------------------------------------------------------ per video
@dataclass(frozen=True)
class TouchObservation:
    """Observability of one ground-truth touch in one study video (one CSV row).

    Attributes
    ----------
    video_id, condition, trajectory : str
        Which video.
    touch : int
        Index of the touch in the trajectory's ground truth (0-based).
    t_start_s, t_end_s : float
        The touch's interval, s.
    in_image, unoccluded, visible : bool
        At the onset (see the module docstring).
    view_angle_deg, px_per_mm, gap_px_per_mm : float
        At the onset; NaN where undefined.
    frames, visible_frames : int
        Video frames inside the touch, and those showing the contact point.
    gap_before_px, gap_min_px, closes_visibly : float, float, bool
        What the rendered video shows of the touch as a silhouette gap between wire and ring
        (:func:`endocam.study.observer.gap_view`): the largest gap just before the onset, the
        smallest gap just before and during it (px, NaN: no frame showed it), and whether the
        gap closes visibly (resolvable just before, seen closed during). Filled in after
        rendering (``study make``); NaN / False until then.
    gap_in_sight : bool or None
        Whether the closing gap itself can be seen at all, from the simulator
        (:func:`gap_in_sight`): the closest-approach point between wire and rim, at the last
        instant before the onset when the gap is still ``GAP_SEEN`` open, is in the image and
        unoccluded from the eye. An observer-independent upper bound on what any assessor can
        see close. ``None``: not computed (files written before the column existed).
    gap_hidden_by : str
        What hides that gap (:func:`~endocam.study.visibility.gap_hidden_by`):
        ``OUTSIDE_IMAGE`` or a geom's name; empty when it is in sight or not computed.
    gap_in_sight_right, gap_hidden_by_right : bool or None, str
        The same from the right eye (:mod:`endocam.study.visibility`).
    gap_in_sight_either : bool or None
        Either eye sees the closing gap.
    gap_px : float
        Pixels the 0.5 mm closing gap spans along the contact normal, in the eye that sees it
        best (both if neither does), px; NaN: not computed or undefined.
    resolved : bool or None
        In sight from an eye where it spans at least ``RESOLVED_PX`` (2 px): the headline.
    """

    video_id: str
    condition: str
    trajectory: str
    touch: int
    t_start_s: float
    t_end_s: float
    in_image: bool
    unoccluded: bool
    visible: bool
    view_angle_deg: float
    px_per_mm: float
    gap_px_per_mm: float
    frames: int
    visible_frames: int
    gap_before_px: float = math.nan
    gap_min_px: float = math.nan
    closes_visibly: bool = False
    gap_in_sight: bool | None = None
    gap_hidden_by: str = ""
    gap_in_sight_right: bool | None = None
    gap_hidden_by_right: str = ""
    gap_in_sight_either: bool | None = None
    gap_px: float = math.nan
    resolved: bool | None = None


def hidden_counts(records: Sequence[TouchObservation]) -> dict[str, int] | None:
    """How many closing gaps each thing hides, most first; None when that was not recorded.

    Not recorded: a record without ``gap_in_sight``, or one not in sight without
    ``gap_hidden_by`` (a folder made before the column; ``study observe`` fills it in).
    """
    hiders = [r.gap_hidden_by for r in records if r.gap_in_sight is False]
    if any(r.gap_in_sight is None for r in records) or not all(hiders):
        return None
    return count_hiders(hiders)


def count_hiders(hiders: Sequence[str]) -> dict[str, int]:
    """``{what: touches}`` over a list of hiders, most first (ties by name)."""
    counts: dict[str, int] = {}
    for h in hiders:
        counts[h] = counts.get(h, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def gap_columns(gap: ClosingGap) -> dict[str, Any]:
    """The closing-gap fields of a :class:`TouchObservation`, from both eyes' view of the gap."""
    return {
        "gap_in_sight": gap.left.in_sight,
        "gap_hidden_by": gap.left.hidden_by or "",
        "gap_in_sight_right": gap.right.in_sight,
        "gap_hidden_by_right": gap.right.hidden_by or "",
        "gap_in_sight_either": gap.in_sight_either,
        "gap_px": gap.gap_px,
        "resolved": gap.resolved,
    }


def row_columns(row: dict[str, Any]) -> dict[str, Any]:
    """:func:`gap_columns` from a closing gap's JSON row (``visibility.gap_row``)."""
    return {
        "gap_in_sight": row["in_sight_left"],
        "gap_hidden_by": row["hidden_by_left"] or "",
        "gap_in_sight_right": row["in_sight_right"],
        "gap_hidden_by_right": row["hidden_by_right"] or "",
        "gap_in_sight_either": row["in_sight_either"],
        "gap_px": math.nan if row["gap_px"] is None else row["gap_px"],
        "resolved": row["resolved"],
    }


def hidden_from_both(records: Sequence[TouchObservation]) -> dict[str, int] | None:
    """What hides the closing gaps no eye sees, by kind (:func:`hider_kind`), most first.

    The left eye's hider names each such touch. None when not recorded (a folder made before
    the stereo columns).
    """
    if any(r.gap_in_sight_either is None for r in records):
        return None
    return count_hiders(
        [hider_kind(r.gap_hidden_by) for r in records if r.gap_in_sight_either is False]
    )


def by_seed(records: Sequence[TouchObservation], field: str) -> dict[str, list[bool]] | None:
    """Per video (one noise seed each), the flags ``field`` of its touches; None if unknown."""
    out: dict[str, list[bool]] = {}
    for r in records:
        flag = getattr(r, field)
        if flag is None:
            return None
        out.setdefault(r.video_id, []).append(bool(flag))
    return out


def observe_episode(
    result: EpisodeResult,
    scene: WireChaserScene,
    *,
    video_id: str,
    condition: str,
    trajectory: str,
    eye: Eye = "left",
) -> list[TouchObservation]:
    """Observability of every ground-truth touch of an episode, as its video shows it.

    The ring pose at a touch's onset is the trajectory's exact pose; the camera pose is the
    logged one at the nearest control step. Frames are the video's (``frame_indices``), each at
    time ``j / video_fps``.

    Parameters
    ----------
    result : EpisodeResult
        A finished episode (its ``touches`` are the ground truth).
    scene : WireChaserScene
        A scene of the same task and camera (its poses are changed).
    video_id, condition, trajectory : str
        Labels copied into the records.
    eye : {"left", "right"}

    Returns
    -------
    list of TouchObservation
        In touch order.
    """
    from endocam.task.touches import clearances

    fps = result.config.episode.video_fps
    n_frames = math.floor(result.trajectory.duration * fps + 1e-9) + 1
    frame_t = np.arange(n_frames) / fps
    ring_cfg = result.config.task.ring
    records = []
    for i, ev in enumerate(result.touches.events):
        T_ring = result.trajectory.pose(ev.t_start)
        _, p_onset = clearances(T_ring[None], result.wire, ring_cfg)
        scene.set_psm2_tip(result.log.p_world_tips[control_step(result, ev.t_start), 1])
        view = observe_contact(
            scene, T_ring, result.log.T_world_cam[control_step(result, ev.t_start)], p_onset[0], eye
        )
        inside = frame_t[(frame_t >= ev.t_start) & (frame_t <= ev.t_end)]
        seen = 0
        if inside.size:
            T_rings = result.trajectory.poses(inside)
            _, p_frames = clearances(T_rings, result.wire, ring_cfg)
            for t, T_r, p in zip(inside, T_rings, p_frames, strict=True):
                k = control_step(result, float(t))
                T_cam = result.log.T_world_cam[k]
                scene.set_psm2_tip(result.log.p_world_tips[k, 1])
                scene.set_ring_pose(T_r)
                scene.set_camera_pose(T_cam)
                if in_image(scene.camera, T_cam, p, eye) and scene.ray_visible(p, T_cam, eye):
                    seen += 1
        gap = closing_gap(result, scene, float(ev.t_start))
        records.append(
            TouchObservation(
                video_id=video_id,
                condition=condition,
                trajectory=trajectory,
                touch=i,
                t_start_s=float(ev.t_start),
                t_end_s=float(ev.t_end),
                in_image=view.in_image,
                unoccluded=view.unoccluded,
                visible=view.visible,
                view_angle_deg=view.view_angle_deg,
                px_per_mm=view.px_per_mm,
                gap_px_per_mm=view.gap_px_per_mm,
                frames=int(inside.size),
                visible_frames=seen,
                **gap_columns(gap),
            )
        )
    return records


# -------------------------------------------------------------------------------- summary
class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ConditionObservability(_Frozen):
    """Per-condition summary over every touch of the condition's videos.

    ``None`` where there is nothing to summarise (no touches, or no finite values).
    """

    touches: Annotated[int, Field(ge=0)]
    visible_share: float | None
    in_image_share: float | None
    unoccluded_share: float | None
    median_view_angle_deg: float | None
    median_px_per_mm: float | None
    median_gap_px_per_mm: float | None
    visible_frame_share: float | None
    touches_without_frame: Annotated[int, Field(ge=0)]
    median_gap_before_px: float | None = None
    closes_visibly_share: float | None = None
    gap_in_sight_share: float | None = None
    gap_hidden_by: dict[str, int] | None = None  # touches per hider; None: not recorded
    resolved: ShareCI | None = None  # the headline (endocam.study.visibility)
    gap_in_sight_either: ShareCI | None = None
    gap_in_sight_left: ShareCI | None = None
    gap_in_sight_right_share: float | None = None
    median_gap_px: float | None = None
    hidden_from_both: dict[str, int] | None = None  # touches per hider kind; None: not recorded


class ObservabilitySummary(_Frozen):
    """The summary part of ``observability.json``, keyed by condition name (in study order)."""

    eye: str
    instant: str
    conditions: dict[str, ConditionObservability]


def finite_median(values: Sequence[float]) -> float | None:
    """Median of the finite values (None: there are none)."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else None


def known_share(flags: Sequence[bool | None]) -> float | None:
    """Share of True among the known (not None) flags (None: none is known)."""
    known = [f for f in flags if f is not None]
    return float(np.mean(known)) if known else None


def seed_share(records: Sequence[TouchObservation], field: str) -> ShareCI | None:
    """Share of ``field`` over the records with its seed-level interval (one video = one seed)."""
    flags = by_seed(records, field)
    return None if flags is None else share_ci(flags)


def summarize(
    records: Sequence[TouchObservation],
    eye: Eye = "left",
    conditions: Sequence[str] | None = None,
) -> ObservabilitySummary:
    """Per-condition summary: share visible (in image, unoccluded), medians, frame coverage.

    ``conditions``: the study's conditions, in order (an entry each, empty ones too); default:
    the conditions of ``records`` in order of appearance.

    The closing gap (:mod:`endocam.study.visibility`): ``resolved`` (the headline),
    ``gap_in_sight_either`` and ``gap_in_sight_left``, each a share with a seed-level bootstrap
    95 % interval (each video is one noise seed), the right eye's share, the median ``gap_px``
    and ``hidden_from_both`` (what hides the gaps neither eye sees, by kind).

    The image-space columns: ``median_gap_before_px`` (median over touches of the gap seen just
    before each onset) and ``closes_visibly_share`` (share of touches whose gap closes visibly).

    ``visible_frame_share`` is the fraction of all in-touch video frames of the condition in
    which the contact point was visible; ``touches_without_frame`` counts touches that no video
    frame shows (shorter than a frame interval).
    """
    names = list(dict.fromkeys(r.condition for r in records)) if conditions is None else conditions
    out = {}
    for condition in names:
        rs = [r for r in records if r.condition == condition]
        frames = sum(r.frames for r in rs)
        out[condition] = ConditionObservability(
            touches=len(rs),
            visible_share=known_share([r.visible for r in rs]),
            in_image_share=known_share([r.in_image for r in rs]),
            unoccluded_share=known_share([r.unoccluded for r in rs]),
            median_view_angle_deg=finite_median([r.view_angle_deg for r in rs]),
            median_px_per_mm=finite_median([r.px_per_mm for r in rs]),
            median_gap_px_per_mm=finite_median([r.gap_px_per_mm for r in rs]),
            visible_frame_share=sum(r.visible_frames for r in rs) / frames if frames else None,
            touches_without_frame=sum(1 for r in rs if r.frames == 0),
            median_gap_before_px=finite_median([r.gap_before_px for r in rs]),
            closes_visibly_share=known_share([r.closes_visibly for r in rs]),
            gap_in_sight_share=known_share([r.gap_in_sight for r in rs]),
            gap_hidden_by=hidden_counts(rs),
            resolved=seed_share(rs, "resolved"),
            gap_in_sight_either=seed_share(rs, "gap_in_sight_either"),
            gap_in_sight_left=seed_share(rs, "gap_in_sight"),
            gap_in_sight_right_share=known_share([r.gap_in_sight_right for r in rs]),
            median_gap_px=finite_median([r.gap_px for r in rs]),
            hidden_from_both=hidden_from_both(rs),
        )
    return ObservabilitySummary(eye=eye, instant="touch onset (t_start)", conditions=out)


def _finite(value: object) -> object:
    return None if isinstance(value, float) and not math.isfinite(value) else value


def observability_json(summary: ObservabilitySummary, records: Sequence[TouchObservation]) -> str:
    """``observability.json``: ``{"eye", "instant", "conditions": {...}, "touches": [...]}``."""
    doc = summary.model_dump(mode="json")
    doc["touches"] = [{k: _finite(v) for k, v in asdict(r).items()} for r in records]
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def observability_csv(records: Sequence[TouchObservation]) -> str:
    """``observability.csv``: one row per touch and video, the fields of TouchObservation."""
    buf = io.StringIO()
    names = list(TouchObservation.__dataclass_fields__)
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(names)
    for r in records:
        row = asdict(r)
        writer.writerow(["" if _finite(row[n]) is None else row[n] for n in names])
    return buf.getvalue()


def load_summary(path: str | Path) -> ObservabilitySummary:
    """Read the summary part of an ``observability.json`` (the per-touch list is ignored).

    Raises
    ------
    ValueError
        One line if the file is unreadable or malformed.
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read {p}: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{p}: expected a JSON object")
    doc.pop("touches", None)
    try:
        return ObservabilitySummary.model_validate(doc)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(x) for x in first["loc"])
        raise ValueError(f"{p}: {where}: {first['msg']}") from None
