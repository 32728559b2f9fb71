"""``endocam compile``: a short episode of every policy on every carrier fills numba's cache.

The compile itself is exercised by ``make test`` (its ``kernels`` step runs before the suite);
these tests check what it runs and how it refuses bad input, without running episodes.
"""

from __future__ import annotations

import pytest

from endocam.cli import main
from endocam.config import ExperimentConfig
from endocam.registry import POLICIES
from endocam.robot.actuator import ArmKind
from endocam.runner import precompile as precompile_module
from endocam.runner.episode import EpisodeSpec
from endocam.runner.precompile import PrecompileJob, precompile, precompile_jobs


def test_every_policy_and_every_carrier_is_compiled() -> None:
    jobs = precompile_jobs()
    assert len(set(jobs)) == len(jobs)  # no episode twice
    assert {job.policy for job in jobs} == set(POLICIES)
    assert {job.arm for job in jobs} == set(ArmKind)
    for arm in ArmKind:  # a policy free to run on any carrier is compiled on each
        assert PrecompileJob(arm, "endocam") in jobs
    assert [job.arm for job in jobs if job.policy == "orientation-ecm"] == [ArmKind.ECM]
    free = precompile_jobs([ArmKind.FREE])  # `endocam compile --arm free`
    assert {job.arm for job in free} == {ArmKind.FREE} and len(free) == len(POLICIES) - 1
    arms = precompile_jobs([ArmKind.PSM, ArmKind.ECM])
    assert sorted(free + arms, key=jobs.index) == jobs  # the two halves make the whole


def test_each_job_runs_one_episode_of_the_asked_duration(monkeypatch: pytest.MonkeyPatch) -> None:
    ran: list[tuple[str, str, float]] = []

    def fake_run(config: ExperimentConfig, spec: EpisodeSpec) -> None:
        ran.append((config.episode.arm.value, spec.policy, config.task.trajectory.duration))

    monkeypatch.setattr("endocam.runner.episode.run_episode", fake_run)
    seen: list[PrecompileJob] = []
    duration_s = 0.25  # s
    assert precompile(duration_s, done=seen.append) == len(precompile_jobs())
    assert seen == precompile_jobs()
    assert ran == [(j.arm.value, j.policy, duration_s) for j in precompile_jobs()]
    with pytest.raises(ValueError, match="duration"):
        precompile(0.0)
    assert precompile_module.DEFAULT_DURATION_S > 0.0


@pytest.mark.parametrize(
    "args",
    [["--duration", d] for d in ("0", "-1", "nan", "inf", "61", "two")]
    + [["--arm", a] for a in ("foo", "psm,arm", ",")],
)
def test_bad_input_is_one_line_exit_2(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["compile", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and args[0] in err[0], err
