"""Response rows: the exchange format between the web app's export and the analysis.

The CSV has exactly the columns ``participant_id,video_id,reported_touches,attention_passed``;
``attention_passed`` is ``true``, ``false`` or empty (the participant never answered the attention
question).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from endocam.study.manifest import MAX_TOUCHES

CSV_COLUMNS = ("participant_id", "video_id", "reported_touches", "attention_passed")
_TRUE = {"true", "1", "yes"}
_FALSE = {"false", "0", "no"}


class ResponseRow(BaseModel):
    """One answer: participant ``participant_id`` reported ``reported_touches`` for a video."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    participant_id: Annotated[str, Field(min_length=1)]
    video_id: Annotated[str, Field(min_length=1)]
    reported_touches: Annotated[int, Field(ge=0, le=MAX_TOUCHES)]
    attention_passed: bool | None


def _bool_cell(text: str) -> bool | None:
    value = text.strip().lower()
    if value == "":
        return None
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise ValueError(f"attention_passed must be true, false or empty, got {text!r}")


def rows_to_csv(rows: Iterable[ResponseRow]) -> str:
    """Render rows as CSV text with the header :data:`CSV_COLUMNS`."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for r in rows:
        passed = "" if r.attention_passed is None else str(r.attention_passed).lower()
        writer.writerow([r.participant_id, r.video_id, r.reported_touches, passed])
    return out.getvalue()


def rows_from_csv(text: str) -> list[ResponseRow]:
    """Parse CSV text written by :func:`rows_to_csv` (or by hand in the same format).

    Raises
    ------
    ValueError
        Wrong header or a bad cell; the message names the line.
    """
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or tuple(h.strip() for h in header) != CSV_COLUMNS:
        raise ValueError(f"responses CSV header must be {','.join(CSV_COLUMNS)}, got {header}")
    rows = []
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        if len(cells) != len(CSV_COLUMNS):
            raise ValueError(f"line {line}: expected {len(CSV_COLUMNS)} cells, got {len(cells)}")
        pid, vid, count, passed = (c.strip() for c in cells)
        if not (count.isascii() and count.isdigit()):
            raise ValueError(
                f"line {line}: reported_touches must be an integer >= 0, got {count!r}"
            )
        try:
            rows.append(
                ResponseRow(
                    participant_id=pid,
                    video_id=vid,
                    reported_touches=int(count),
                    attention_passed=_bool_cell(passed),
                )
            )
        except ValidationError as exc:
            err = exc.errors()[0]
            raise ValueError(f"line {line}: {err['loc'][0]}: {err['msg']}") from None
        except ValueError as exc:
            raise ValueError(f"line {line}: {exc}") from None
    return rows


def read_responses_csv(path: str | Path) -> list[ResponseRow]:
    """Read a responses CSV file (see :func:`rows_from_csv`)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read responses {path}: {exc.strerror or exc}") from None
    try:
        return rows_from_csv(text)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
