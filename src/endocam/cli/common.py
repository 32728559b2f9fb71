"""What every ``endocam`` subcommand shares: the one-line usage error and argument types.

Nothing here imports a subcommand module, so the subcommands import it without a cycle.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NoReturn

from endocam.config import ExperimentConfig, config_from_mapping, load_config, load_faults
from endocam.perception.loop import PerceptionSource
from endocam.robot.carriers import ArmKind

EXIT_USAGE = 2
EXIT_INTERNAL = 1
EXIT_UNSAFE = 3  # a run or experiment wrote its results, and its safety check found violations
ARM_CHOICES = tuple(k.value for k in ArmKind)  # the carrier choices, from their one source
PERCEPTION_CHOICES = tuple(s.value for s in PerceptionSource)  # --perception
PERCEPTION_HELP = (
    "where the controller's ring pose comes from: truth (the simulator's, sensing_latency "
    "late) or stereo (the estimator on the rendered stereo images; docs/perception.md); "
    "default: the config's perception.source (truth)"
)
MAX_WORKERS = 64  # count: --workers


class UsageError(Exception):
    """A problem with what the user typed or pointed at; reported as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr with exit code 2."""

    def error(self, message: str) -> NoReturn:
        """Print ``prog: error: message`` (no usage block) and exit with code 2."""
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def integer(text: str) -> int:
    """``type=`` for integer options: a one-line error for anything else."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def check_workers(n: int) -> None:
    """Raise a :class:`UsageError` unless ``--workers`` is in 1..``MAX_WORKERS``."""
    if not 1 <= n <= MAX_WORKERS:
        raise UsageError(f"--workers must be in 1..{MAX_WORKERS}, got {n}")


def load_config_arg(path: str | None) -> ExperimentConfig:
    """The defaults, or the ``--config`` file validated (its problem as a :class:`UsageError`)."""
    if path is None:
        return ExperimentConfig()
    try:
        return load_config(path)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def with_faults(config: ExperimentConfig, path: str | None) -> ExperimentConfig:
    """``config`` with its ``faults`` section replaced by the ``--faults`` file, if given."""
    if path is None:
        return config
    try:
        faults = load_faults(path)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return config.model_copy(update={"faults": faults})


def with_perception(config: ExperimentConfig, source: str | None) -> ExperimentConfig:
    """``config`` with ``perception.source`` replaced by ``--perception``, if given.

    Validated as a whole (a :class:`UsageError` of one line, e.g. a stereo frame rate above
    the control rate).
    """
    if source is None:
        return config
    data = config.model_dump(mode="json")
    data["perception"]["source"] = source
    try:
        return config_from_mapping(data, "--perception")
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def perception_arg(parser: argparse.ArgumentParser) -> None:
    """Add ``--perception truth|stereo`` (:func:`with_perception`) to ``parser``."""
    parser.add_argument("--perception", choices=PERCEPTION_CHOICES, help=PERCEPTION_HELP)


def out_dir(path: str) -> Path:
    """The ``--out`` folder, checked before any work (else a :class:`UsageError`).

    Refused: an empty path, ``.``, the home folder or a folder holding the current or the home
    folder, a file in the way, a non-empty folder endocam did not write (no ``.endocam-output``
    marker), a place that cannot be written (:func:`endocam.runner.outputs.check_output_folder`).
    """
    from endocam.runner.outputs import check_output_folder

    try:
        return check_output_folder(path)
    except ValueError as exc:
        raise UsageError(f"--out: {exc}") from None
