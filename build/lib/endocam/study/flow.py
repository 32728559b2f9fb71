"""The participant's path through the study, as a pure function of what is already answered.

A participant (who has given consent to start a session) first answers the optional demographic
questions and the optional practice video, then, with presentation order ``(A, B, C)``, sees set 1
= the videos of condition A, then set 2 = condition B, then the attention question, then set 3 =
condition C. Within a set the videos appear in a random order drawn once per participant from a
stored seed (:func:`video_sequence`; manifest order with ``shuffle_within_set = false``). The
attention question sits between the second and the last set (``attention_after_set``), i.e. after
six of the nine answers: in the middle of the form, as in the paper, without splitting a set.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from endocam.study.manifest import Manifest

VideoSequence = tuple[tuple[str, ...], ...]  # video ids per set, in the order shown


class StepKind(StrEnum):
    """What the participant has to do next."""

    DEMOGRAPHICS = "demographics"
    PRACTICE = "practice"
    VIDEO = "video"
    ATTENTION = "attention"
    DONE = "done"


@dataclass(frozen=True)
class Step:
    """The next thing a participant does.

    Attributes
    ----------
    kind : StepKind
        Video, attention question, or done.
    video_id : str or None
        The video to watch and count (``kind == VIDEO`` only).
    set_number : int or None
        1-based set number of that video.
    position_in_set : int or None
        1-based position of the video within its set.
    videos_in_set : int
        Number of videos per set.
    n_sets : int
        Number of sets.
    n_answered : int
        Videos answered so far.
    n_videos : int
        Videos in the whole study.
    """

    kind: StepKind
    video_id: str | None
    set_number: int | None
    position_in_set: int | None
    videos_in_set: int
    n_sets: int
    n_answered: int
    n_videos: int


def attention_after_set(n_sets: int) -> int:
    """Number of sets shown before the attention question: the one before the last (≥ 1)."""
    if n_sets < 1:
        raise ValueError(f"n_sets must be >= 1, got {n_sets}")
    return max(1, n_sets - 1)


def video_sequence(manifest: Manifest, order_index: int, seed: int) -> VideoSequence:
    """Video ids per set for presentation order ``order_index``, shuffled within each set.

    Parameters
    ----------
    manifest : Manifest
        The study; ``shuffle_within_set = false`` keeps the manifest order.
    order_index : int
        Index into ``manifest.orders``.
    seed : int
        The participant's shuffle seed (``np.random.default_rng``).

    Returns
    -------
    tuple of n_sets tuples of video ids
        Set ``i`` holds the videos of the ``i``-th condition of the order.
    """
    if not 0 <= order_index < len(manifest.orders):
        raise ValueError(f"order_index must be in [0, {len(manifest.orders)}), got {order_index}")
    rng = np.random.default_rng(seed)
    sets = []
    for condition in manifest.orders[order_index]:
        ids = [v.id for v in manifest.videos_of(condition)]
        if manifest.shuffle_within_set:
            ids = [ids[i] for i in rng.permutation(len(ids))]
        sets.append(tuple(ids))
    return tuple(sets)


def next_step(
    sets: VideoSequence,
    answered: Collection[str],
    attention_done: bool,
    *,
    demographics_due: bool = False,
    practice_due: bool = False,
) -> Step:
    """The first unanswered item of the participant's sequence.

    Parameters
    ----------
    sets : tuple of tuples of video ids
        The participant's stored :func:`video_sequence`.
    answered : collection of str
        Ids of the videos already answered.
    attention_done : bool
        Whether the attention question is answered.
    demographics_due, practice_due : bool
        Whether the demographic questions / the practice video still have to be answered.

    Returns
    -------
    Step
        The demographics, the practice video, a video, the attention question, or done.
    """
    if not sets or not sets[0]:
        raise ValueError("sets must hold at least one non-empty set")
    n_videos = sum(len(s) for s in sets)
    per_set = len(sets[0])
    n_answered = sum(1 for s in sets for vid in s if vid in answered)
    common = {"videos_in_set": per_set, "n_sets": len(sets), "n_answered": n_answered}
    for kind, due in ((StepKind.DEMOGRAPHICS, demographics_due), (StepKind.PRACTICE, practice_due)):
        if due:
            return Step(kind, None, None, None, n_videos=n_videos, **common)
    for set_index, video_ids in enumerate(sets):
        if set_index == attention_after_set(len(sets)) and not attention_done:
            return Step(StepKind.ATTENTION, None, None, None, n_videos=n_videos, **common)
        for position, vid in enumerate(video_ids):
            if vid not in answered:
                return Step(
                    StepKind.VIDEO, vid, set_index + 1, position + 1, n_videos=n_videos, **common
                )
    if not attention_done:  # single-set study: the question comes last
        return Step(StepKind.ATTENTION, None, None, None, n_videos=n_videos, **common)
    return Step(StepKind.DONE, None, None, None, n_videos=n_videos, **common)
