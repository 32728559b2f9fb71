"""Response rows: the exchange format between the web app's export and the analysis.

The analysis needs the columns ``participant_id,video_id,reported_touches,attention_passed``;
``attention_passed`` is ``true``, ``false`` or empty (the participant never answered the attention
question). Other columns (the web app's full export, see :mod:`endocam.study.export`) are ignored,
except ``in_analysis``: rows where it is ``false`` (a participant's later attempts) are skipped, so
the export can be analysed as it is. Files are read as UTF-8 with or without a byte-order mark
(what spreadsheets write).

:func:`parse_count` is the one rule for a typed touch count: ASCII digits only (no sign, no
decimal point, no ``_``), 0..``MAX_TOUCHES``; the web forms and the CSV reader both use it, and it
accepts exactly what the JSON API's strict integer accepts.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from endocam.study.manifest import MAX_TOUCHES

CSV_COLUMNS = ("participant_id", "video_id", "reported_touches", "attention_passed")
IN_ANALYSIS = "in_analysis"  # optional column: rows marked false are not analysed
_TRUE = {"true", "1", "yes"}
_FALSE = {"false", "0", "no"}


class ResponseRow(BaseModel):
    """One answer: participant ``participant_id`` reported ``reported_touches`` for a video."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    participant_id: Annotated[str, Field(min_length=1)]
    video_id: Annotated[str, Field(min_length=1)]
    reported_touches: Annotated[int, Field(ge=0, le=MAX_TOUCHES)]
    attention_passed: bool | None


MAX_COUNT_CHARS = 8  # longest count text looked at (leading zeros allowed)


def parse_count(text: str, maximum: int = MAX_TOUCHES) -> int:
    """Parse a typed whole number (a touch count, or years of training).

    Parameters
    ----------
    text : str
        What was typed; surrounding white space is ignored.
    maximum : int
        Largest value accepted (default: ``MAX_TOUCHES`` touches).

    Returns
    -------
    int
        The number, 0..``maximum``.

    Raises
    ------
    ValueError
        Not a whole number written with ASCII digits only, or out of range.
    """
    value = text.strip()
    if not (0 < len(value) <= MAX_COUNT_CHARS and value.isascii() and value.isdigit()):
        raise ValueError(f"must be a whole number from 0 to {maximum} written with digits only")
    count = int(value)
    if count > maximum:
        raise ValueError(f"must be a whole number from 0 to {maximum}, got {count}")
    return count


def _bool_cell(text: str, column: str = "attention_passed") -> bool | None:
    value = text.strip().lower()
    if value == "":
        return None
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise ValueError(f"{column} must be true, false or empty, got {text!r}")


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
    """Parse CSV text with at least the columns :data:`CSV_COLUMNS` (others are ignored).

    Raises
    ------
    ValueError
        A missing column, a bad cell or no data rows at all; the message names the line.
    """
    reader = csv.reader(io.StringIO(text.removeprefix("\ufeff")))
    try:
        return _rows(reader)
    except csv.Error as exc:  # a field over csv.field_size_limit(), a NUL byte, ...
        raise ValueError(f"line {reader.line_num}: {exc}") from None


def _rows(reader: Any) -> list[ResponseRow]:
    """The rows of a CSV reader (see :func:`rows_from_csv`)."""
    header = [h.strip() for h in next(reader, None) or []]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise ValueError(
            f"responses CSV needs the columns {','.join(CSV_COLUMNS)}; missing {','.join(missing)}"
        )
    index = [header.index(c) for c in CSV_COLUMNS]
    use = header.index(IN_ANALYSIS) if IN_ANALYSIS in header else None
    rows = []
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        if len(cells) != len(header):
            raise ValueError(f"line {line}: expected {len(header)} cells, got {len(cells)}")
        if use is not None and _bool_cell(cells[use], IN_ANALYSIS) is False:
            continue
        pid, vid, count, passed = (cells[i].strip() for i in index)
        try:
            rows.append(
                ResponseRow(
                    participant_id=pid,
                    video_id=vid,
                    reported_touches=parse_count(count),
                    attention_passed=_bool_cell(passed),
                )
            )
        except ValidationError as exc:
            err = exc.errors()[0]
            raise ValueError(f"line {line}: {err['loc'][0]}: {err['msg']}") from None
        except ValueError as exc:
            raise ValueError(f"line {line}: {exc}") from None
    if not rows:
        raise ValueError("no answers: the CSV has a header but no data rows")
    return rows


def read_responses_csv(path: str | Path) -> list[ResponseRow]:
    """Read a responses CSV file, UTF-8 with or without BOM (see :func:`rows_from_csv`)."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ValueError(f"cannot read responses {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: not UTF-8 text (byte {exc.start}); save the CSV as UTF-8"
        ) from None
    try:
        return rows_from_csv(text)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
