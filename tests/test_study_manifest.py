import json
from pathlib import Path

import pytest

from endocam.study.flow import StepKind, attention_after_set, next_step, video_sequence
from endocam.study.manifest import (
    DEFAULT_TOUCH_DEFINITION,
    ManifestError,
    load_manifest,
    parse_manifest,
)
from study_helpers import manifest_dict

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)


def _text(doc: dict) -> str:
    return json.dumps(doc)


def test_valid_manifest_parses_and_answers_queries() -> None:
    m = parse_manifest(_text(manifest_dict()))
    assert len(m.videos) == 9
    assert m.most_difficult("centering").id == "v06"
    assert [v.id for v in m.videos_of("orientation")] == ["v07", "v08", "v09"]
    assert parse_manifest(m.model_dump_json()) == m


def test_touch_definition_is_read_and_defaults_for_older_manifests() -> None:
    doc = manifest_dict()
    doc.pop("touch_definition", None)  # a manifest written before the field existed
    assert parse_manifest(_text(doc)).touch_definition == DEFAULT_TOUCH_DEFINITION
    doc["touch_definition"] = "Count every contact."
    assert parse_manifest(_text(doc)).touch_definition == "Count every contact."


def _broken(edit) -> str:
    doc = manifest_dict()
    edit(doc)
    return _text(doc)


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda d: d["videos"][1].update(id="v01"), "unique"),
        (lambda d: d["videos"].pop(), "one video per trajectory"),
        (lambda d: d["videos"][0].update(difficulty=4), "difficulty"),
        (lambda d: d["videos"][0].update(true_touches=-1), "true_touches"),
        (lambda d: d["videos"][0].update(file="../x.mp4"), "relative POSIX path"),
        (lambda d: d["videos"][0].update(file="/abs/x.mp4"), "relative POSIX path"),
        (lambda d: d["videos"][0].update(condition="zoom"), "condition"),
        (lambda d: d.update(conditions=["fixed", "centering"]), "conditions"),
        (lambda d: d.update(conditions=["fixed"]), "at least 2 distinct conditions"),
        (lambda d: d.update(conditions=["fixed", "fixed", "orientation"]), "distinct"),
        (lambda d: d["videos"][0].update(condition="Fixed!"), "pattern"),
        (lambda d: d["orders"].append(["fixed", "fixed", "orientation"]), "permutation"),
        (lambda d: d["orders"].append(d["orders"][0]), "distinct"),
        (lambda d: d.update(orders=[]), "orders"),
        (lambda d: d["attention"].update(answer="four"), "attention"),
        (lambda d: d.pop("created"), "created"),
        (lambda d: d.update(touch_definition=""), "touch_definition"),
    ],
)
def test_invalid_manifests_give_one_line_errors(edit, needle: str) -> None:
    with pytest.raises(ManifestError) as info:
        parse_manifest(_broken(edit))
    message = str(info.value)
    assert needle in message
    assert "\n" not in message


def test_same_difficulty_for_two_trajectories_is_rejected() -> None:
    def edit(doc: dict) -> None:
        for v in doc["videos"]:
            if v["trajectory"] == "t2-36-high":
                v["difficulty"] = 3

    with pytest.raises(ManifestError, match="own difficulty"):
        parse_manifest(_broken(edit))


def test_loading_a_folder_checks_video_files(tmp_path: Path) -> None:
    (tmp_path / "manifest.json").write_text(_text(manifest_dict()), encoding="utf-8")
    with pytest.raises(ManifestError, match="video files missing"):
        load_manifest(tmp_path)
    # the file alone is enough for the analysis
    assert len(load_manifest(tmp_path / "manifest.json").videos) == 9
    with pytest.raises(ManifestError, match="cannot read"):
        load_manifest(tmp_path / "nope.json")


def test_flow_puts_attention_between_set_two_and_three() -> None:
    m = parse_manifest(_text(manifest_dict() | {"shuffle_within_set": False}))
    assert attention_after_set(3) == 2
    order = 1  # centering, orientation, fixed
    sets = video_sequence(m, order, seed=0)
    assert sets == (
        ("v04", "v05", "v06"),
        ("v07", "v08", "v09"),
        ("v01", "v02", "v03"),
    )
    answered: list[str] = []
    seen = []
    attention = False
    for _ in range(20):
        step = next_step(sets, answered, attention)
        seen.append(step.video_id or step.kind.value)
        if step.kind == StepKind.VIDEO:
            answered.append(step.video_id)
        elif step.kind == StepKind.ATTENTION:
            attention = True
        else:
            break
    assert seen == [
        "v04",
        "v05",
        "v06",
        "v07",
        "v08",
        "v09",
        "attention",
        "v01",
        "v02",
        "v03",
        "done",
    ]
    with pytest.raises(ValueError, match="order_index"):
        video_sequence(m, 6, seed=0)


def test_a_manifest_of_four_conditions_and_their_williams_orders_is_valid() -> None:
    from endocam.study.counterbalance import presentation_orders

    doc = manifest_dict()
    extra = [
        dict(v, id=f"w{k}", condition="endocam", file=f"videos/w{k}.mp4")
        for k, v in enumerate(doc["videos"][:3])
    ]
    doc["videos"] += extra
    doc["conditions"] = [*doc["conditions"], "endocam"]
    doc["orders"] = [list(o) for o in presentation_orders(doc["conditions"])]
    m = parse_manifest(_text(doc))
    assert len(m.conditions) == 4 and len(m.orders) == 4
    assert [v.id for v in m.videos_of("endocam")] == ["w0", "w1", "w2"]


def test_condition_policies_come_from_the_design_or_the_legacy_names() -> None:
    from endocam.study.manifest import condition_policies

    four = ["fixed", "centering", "orientation", "endocam"]
    assert condition_policies({"conditions": {c: c for c in four}}, four) == {c: c for c in four}
    legacy = condition_policies({}, ["fixed", "centering", "orientation"])  # before round 9
    assert legacy == {"fixed": "fixed", "centering": "centering", "orientation": "endocam"}
