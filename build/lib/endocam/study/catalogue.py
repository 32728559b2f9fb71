"""The message catalogue: every participant-facing text of the study app, in one JSON file.

:file:`study/messages/en.json` is the default. A study runs in another language by shipping its
own catalogue in the study folder and naming it in the manifest (``"messages_file":
"messages/de.json"``); it must have exactly the default's keys and, per key, the same
``{placeholders}``, which :func:`load_catalogue` checks before the server starts. The key ``lang``
is the page's language tag (``<html lang>``).
"""

from __future__ import annotations

import json
import string
from collections.abc import Mapping
from pathlib import Path

MESSAGES_DIR = Path(__file__).parent / "messages"
DEFAULT_CATALOGUE = MESSAGES_DIR / "en.json"


def _placeholders(text: str) -> set[str]:
    return {name for _, name, _, _ in string.Formatter().parse(text) if name}


class Catalogue:
    """Texts by key; calling it fills in the placeholders.

    Parameters
    ----------
    messages : mapping str → str
        The texts, with ``{name}`` placeholders.
    """

    def __init__(self, messages: Mapping[str, str]) -> None:
        self._messages = dict(messages)

    @property
    def lang(self) -> str:
        """The catalogue's language tag."""
        return self._messages["lang"]

    def __call__(self, key: str, **values: object) -> str:
        """The text ``key`` with ``values`` filled in (KeyError for an unknown key)."""
        return self._messages[key].format(**values)

    def paragraphs(self, key: str) -> list[str]:
        """The text ``key`` split at blank lines."""
        return [p.strip() for p in self._messages[key].split("\n\n") if p.strip()]


def _read(path: Path) -> dict[str, str]:
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"messages {path}: cannot read a JSON catalogue ({exc})") from None
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in data.items()
    ):
        raise ValueError(f"messages {path}: must be a JSON object of strings")
    return data


def load_catalogue(path: str | Path | None = None) -> Catalogue:
    """Load the default catalogue or a replacement with the same keys and placeholders.

    Parameters
    ----------
    path : str or Path, optional
        A catalogue JSON file; None gives the default (English).

    Returns
    -------
    Catalogue
        The texts.

    Raises
    ------
    ValueError
        Unreadable file, missing or unknown keys, or placeholders that differ (one line).
    """
    default = _read(DEFAULT_CATALOGUE)
    if path is None:
        return Catalogue(default)
    other = _read(Path(path))
    missing, unknown = sorted(set(default) - set(other)), sorted(set(other) - set(default))
    if missing or unknown:
        raise ValueError(f"messages {path}: missing keys {missing}, unknown keys {unknown}")
    for key, text in default.items():
        if _placeholders(other[key]) != _placeholders(text):
            raise ValueError(
                f"messages {path}: {key!r} must use the placeholders {sorted(_placeholders(text))}"
            )
    return Catalogue(other)
