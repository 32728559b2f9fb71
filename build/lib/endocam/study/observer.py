"""An automatic assessor: count ring–wire touches from a rendered video alone.

The paper's claim is that people count touches more accurately when the camera follows the
ring's orientation. Before anyone watches a video, this observer counts the touches the way an
assessor would, from the decoded left-eye MP4 and nothing else (no pose, no clearance, no ground
truth inside the counter): it only knows what the ring and the wire look like (their colours,
as a participant is told "the orange ring, the blue wire") and their shapes.

Per frame, :func:`~endocam.study.observer_frame.frame_gap_px` (in
:mod:`endocam.study.observer_frame`, with the colour segmentation) reads the gap between the
wire's band through the ring's hole and the rim's inner edge, in px, where the hole's edge runs
parallel to the band; it says nothing (NaN) where the place is hidden, the wire there is in
front of the ring, or the ring is too small to resolve a gap. It also knows the ring's and the
wire's shapes (tube and wire radius relative to the ring), as a participant told about the task
does.

Touches (:func:`count_touches`): a frame shows contact when its gap is at most
``CONTACT_GAP_PX``; a frame that shows nothing keeps the previous state (an assessor cannot see
a change). A touch begins at a contact frame and ends only after ``RELEASE_FRAMES`` consecutive
frames with a clearly open gap (more than ``OPEN_GAP_PX``), so a gap flickering open for a few
frames is not a new touch; a touch needs ``MIN_TOUCH_FRAMES`` contact frames. These four numbers
were set on the default study's most difficult trajectory (the validation clips are others).

:func:`observe_video` runs this over a video; :func:`observer_document` and
:func:`observer_html` are ``observer.json`` (per condition: videos, mean and SD of
``|counted − true|``; per video the events) and ``observer.html`` (the frame where each touch
was seen); :func:`endocam.study.hypothesis.recount_study` writes them for a study folder.
:func:`match_events` scores seen against true events (precision and recall), used to validate
the observer on clips with known touches.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import imageio_ffmpeg
import numpy as np
from numpy.typing import NDArray

from endocam.study.manifest import Manifest
from endocam.study.observer_frame import (
    CONTACT_PX,
    RESOLVE_PX,
    ColourKeys,
    frame_gap_px,
    segment,
)
from endocam.task.config import SceneConfig

OBSERVER_JSON = "observer.json"
OBSERVER_HTML = "observer.html"
CONTACT_GAP_PX = CONTACT_PX  # px, a silhouette gap this small reads as contact
OPEN_GAP_PX = RESOLVE_PX  # px, a gap this wide is clearly open: it ends a touch (resolvable)
RELEASE_FRAMES = 8  # consecutive clearly open frames that end a touch (0.27 s at 30 fps)
MIN_TOUCH_FRAMES = 2  # frames of contact a touch needs to be counted (one frame is flicker)
PRE_TOUCH_S = 0.25  # s, "just before" a touch: the window whose gap shows it closing
THUMB_WIDTH_PX = 320  # px, width of the frames in observer.html
JPEG_QUALITY = 85  # 0..100


# --------------------------------------------------------------------------- counting
@dataclass(frozen=True)
class SeenTouch:
    """A touch the observer saw.

    Attributes
    ----------
    frame_start, frame_end : int
        First and last frame showing contact (0-based).
    t_start, t_end : float
        Their times, s (frame / fps).
    min_gap_px : float
        Smallest gap seen during the touch, px.
    """

    frame_start: int
    frame_end: int
    t_start: float
    t_end: float
    min_gap_px: float


def count_touches(gaps_px: Sequence[float] | NDArray[np.float64], fps: float) -> list[SeenTouch]:
    """Touches in a series of per-frame gaps (see the module docstring).

    Parameters
    ----------
    gaps_px : (F,)
        Gap per frame, px; NaN where the frame shows nothing.
    fps : float
        Frame rate, frames/s.

    Returns
    -------
    list of SeenTouch
        In time order.
    """
    if not fps > 0.0:
        raise ValueError(f"fps must be positive, got {fps}")
    gaps = np.asarray(gaps_px, dtype=float)
    touches: list[SeenTouch] = []
    state = False
    start = last_contact = contacts = open_run = 0
    low = math.inf

    def close() -> None:
        if contacts >= MIN_TOUCH_FRAMES:
            touches.append(SeenTouch(start, last_contact, start / fps, last_contact / fps, low))

    for k, g in enumerate(gaps):
        if math.isnan(g):
            continue  # nothing seen: the assessor keeps what they saw last
        if g <= CONTACT_GAP_PX:
            if not state:
                state, start, low, contacts = True, k, math.inf, 0
            last_contact, open_run, low = k, 0, min(low, float(g))
            contacts += 1
        elif state and g > OPEN_GAP_PX:
            open_run += 1
            if open_run >= RELEASE_FRAMES:
                close()
                state = False
    if state:
        close()
    return touches


@dataclass(frozen=True)
class Match:
    """Seen events scored against true ones (one-to-one, by overlapping time).

    Attributes
    ----------
    true_positives : int
        Seen touches matched to a true touch.
    seen, true : int
        Numbers of seen and true touches.
    """

    true_positives: int
    seen: int
    true: int

    @property
    def precision(self) -> float:
        """Matched seen / seen (1 when nothing was seen)."""
        return self.true_positives / self.seen if self.seen else 1.0

    @property
    def recall(self) -> float:
        """Matched true / true (1 when there was nothing to see)."""
        return self.true_positives / self.true if self.true else 1.0


def match_events(
    seen: Sequence[tuple[float, float]], true: Sequence[tuple[float, float]], tolerance_s: float
) -> Match:
    """Pair seen and true touches whose time intervals overlap (each widened by ``tolerance_s``).

    Parameters
    ----------
    seen, true : sequence of (t_start, t_end)
        Touch intervals, s.
    tolerance_s : float
        Allowed slack, s (one frame interval: a seen touch starts at a frame, not at the instant).

    Returns
    -------
    Match
    """
    used: set[int] = set()
    tp = 0
    for s0, s1 in seen:
        for j, (t0, t1) in enumerate(true):
            if j not in used and s0 <= t1 + tolerance_s and t0 <= s1 + tolerance_s:
                used.add(j)
                tp += 1
                break
    return Match(tp, len(seen), len(true))


@dataclass(frozen=True)
class GapView:
    """What a video shows of one true touch, from its per-frame silhouette gaps.

    Attributes
    ----------
    gap_before_px : float
        Largest gap seen in the ``PRE_TOUCH_S`` before the onset, px (NaN: no frame showed it).
    gap_min_px : float
        Smallest gap seen from ``PRE_TOUCH_S`` before the onset to the touch's end, px (NaN: no
        frame showed it).
    closes_visibly : bool
        The gap was resolvable just before (≥ ``OPEN_GAP_PX``) and seen closed (≤
        ``CONTACT_GAP_PX``) in a frame of the touch: not hidden, not too small to see open.
    """

    gap_before_px: float
    gap_min_px: float
    closes_visibly: bool


def gap_view(gaps_px: NDArray[np.float64], fps: float, t_start: float, t_end: float) -> GapView:
    """The silhouette gap around one true touch ``[t_start, t_end]`` (s) in a video's frames.

    Parameters
    ----------
    gaps_px : (F,)
        Per-frame gaps of the video (frame ``k`` at ``k / fps``), px, NaN where nothing is seen.
    fps : float
        Frames/s.
    t_start, t_end : float
        The touch, s.

    Returns
    -------
    GapView
    """
    t = np.arange(gaps_px.size) / fps
    before = gaps_px[(t >= t_start - PRE_TOUCH_S) & (t < t_start)]
    during = gaps_px[(t >= t_start) & (t <= t_end)]
    around = np.concatenate([before, during])
    b = before[np.isfinite(before)]
    d = during[np.isfinite(during)]
    a = around[np.isfinite(around)]
    gap_before = float(b.max()) if b.size else math.nan
    closes = bool(b.size and d.size and gap_before >= OPEN_GAP_PX and d.min() <= CONTACT_GAP_PX)
    return GapView(gap_before, float(a.min()) if a.size else math.nan, closes)


# --------------------------------------------------------------------------- videos
@dataclass(frozen=True)
class VideoObservation:
    """The observer's reading of one video.

    Attributes
    ----------
    gaps_px : (F,)
        Gap per frame, px (NaN: nothing seen).
    touches : list of SeenTouch
    fps : float
    thumbnails : dict
        Frame index → JPEG bytes of the frame where a touch began.
    """

    gaps_px: NDArray[np.float64]
    touches: list[SeenTouch]
    fps: float
    thumbnails: dict[int, bytes]


def observe_frames(
    frames: Sequence[NDArray[np.uint8]] | Any,
    fps: float,
    keys: ColourKeys,
    progress: Callable[[int], object] | None = None,
) -> VideoObservation:
    """Count touches in an iterable of RGB frames (H, W, 3) uint8 at ``fps`` frames/s."""
    gaps: list[float] = []
    starts: dict[int, bytes] = {}
    prev_contact = False
    for k, frame in enumerate(frames):
        ring, wire = segment(frame, keys)
        g = frame_gap_px(ring, wire)
        gaps.append(g)
        contact = (g <= CONTACT_GAP_PX) if not math.isnan(g) else prev_contact
        if contact and not prev_contact:
            starts[k] = _thumbnail(frame, ring, wire)
        prev_contact = contact
        if progress is not None:
            progress(1)
    touches = count_touches(gaps, fps)
    thumbs = {t.frame_start: starts[t.frame_start] for t in touches if t.frame_start in starts}
    return VideoObservation(np.asarray(gaps, dtype=float), touches, fps, thumbs)


def observe_video(
    path: str | Path, keys: ColourKeys, progress: Callable[[int], object] | None = None
) -> VideoObservation:
    """Decode an MP4 (imageio-ffmpeg) and count its touches (:func:`observe_frames`)."""
    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
    meta = next(reader)
    width, height = meta["size"]
    fps = float(meta["fps"])

    def frames() -> Any:
        for buf in reader:
            yield np.frombuffer(buf, dtype=np.uint8).reshape(height, width, 3)

    try:
        return observe_frames(frames(), fps, keys, progress)
    finally:
        reader.close()


def _thumbnail(frame: NDArray[np.uint8], ring: NDArray[np.bool_], wire: NDArray[np.bool_]) -> bytes:
    """JPEG of a frame with the ring's (white) and the wire's (magenta) segmented outlines."""
    bgr = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2BGR)
    for mask, colour in ((ring, (255, 255, 255)), (wire, (255, 0, 255))):
        contours, _ = cv2.findContours(
            mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
        )
        cv2.drawContours(bgr, contours, -1, colour, 1)
    scale = min(1.0, THUMB_WIDTH_PX / bgr.shape[1])
    if scale < 1.0:
        size = (THUMB_WIDTH_PX, max(1, round(bgr.shape[0] * scale)))
        bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
        raise RuntimeError("JPEG encoding failed")
    return bytes(buf)


# --------------------------------------------------------------------------- a study
def observer_summary(
    manifest: Manifest, counted: dict[str, int]
) -> dict[str, dict[str, float | int | None]]:
    """Per condition: videos, mean and sample SD of ``|counted − true|`` touches."""
    out: dict[str, dict[str, float | int | None]] = {}
    for c in manifest.conditions:
        errors = [abs(counted[v.id] - v.true_touches) for v in manifest.videos_of(c)]
        out[c] = {
            "videos": len(errors),
            "mean_abs_error": float(np.mean(errors)),
            "sd_abs_error": float(np.std(errors, ddof=1)) if len(errors) > 1 else None,
        }
    return out


def observer_document(
    manifest: Manifest, observations: dict[str, VideoObservation]
) -> dict[str, Any]:
    """``observer.json``'s content (the schema in the module docstring)."""
    counted = {vid: len(obs.touches) for vid, obs in observations.items()}
    return {
        "conditions": observer_summary(manifest, counted),
        "videos": [
            {
                "id": v.id,
                "condition": v.condition,
                "true_touches": v.true_touches,
                "counted_touches": counted[v.id],
                "events": [asdict(t) for t in observations[v.id].touches],
            }
            for v in manifest.videos
        ],
    }


def observer_html(manifest: Manifest, observations: dict[str, VideoObservation]) -> str:
    """A self-contained page: per video, the frame where each touch was seen (outlines drawn)."""
    doc = observer_document(manifest, observations)
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>",
        "<title>endocam observer</title><style>body{font-family:sans-serif;margin:1em}",
        "figure{display:inline-block;margin:4px}figcaption{font-size:small}</style></head><body>",
        "<h1>Touches the automatic observer saw</h1>",
        "<p>Counted from each video alone (colour segmentation of the ring, white outline, and "
        "the wire, magenta). A touch is a run of frames whose ring–wire silhouette gap is at "
        f"most {CONTACT_GAP_PX} px.</p><table><tr><th>condition</th><th>videos</th>"
        "<th>mean |counted − true|</th><th>SD</th></tr>",
    ]
    for c, row in doc["conditions"].items():
        sd = "–" if row["sd_abs_error"] is None else f"{row['sd_abs_error']:.2f}"
        parts.append(
            f"<tr><td>{html.escape(c)}</td><td>{row['videos']}</td>"
            f"<td>{row['mean_abs_error']:.2f}</td><td>{sd}</td></tr>"
        )
    parts.append("</table>")
    for v in doc["videos"]:
        obs = observations[v["id"]]
        parts.append(
            f"<h2>{html.escape(v['id'])} ({html.escape(v['condition'])}): counted "
            f"{v['counted_touches']}, true {v['true_touches']}</h2>"
        )
        for t in obs.touches:
            jpeg = obs.thumbnails.get(t.frame_start)
            img = (
                f"<img alt='frame {t.frame_start}' src='data:image/jpeg;base64,"
                f"{base64.b64encode(jpeg).decode()}'>"
                if jpeg
                else ""
            )
            parts.append(
                f"<figure>{img}<figcaption>frames {t.frame_start}–{t.frame_end} "
                f"({t.t_start:.2f}–{t.t_end:.2f} s), min gap {t.min_gap_px:.1f} px"
                "</figcaption></figure>"
            )
    parts.append("</body></html>\n")
    return "".join(parts)


def keys_for_study(folder: Path) -> ColourKeys:
    """The colours a study was rendered with (``design.json``), else the default scene's."""
    design = folder / "design.json"
    scene = SceneConfig()
    if design.is_file():
        data = json.loads(design.read_text("utf-8"))
        if "ring_rgba" in data and "wire_rgba" in data:
            return ColourKeys.from_rgba(tuple(data["ring_rgba"]), tuple(data["wire_rgba"]))
    return ColourKeys.from_scene(scene)
