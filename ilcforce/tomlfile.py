"""Reading a user's TOML file (an experiment or a study) with one clear line for every way it can fail."""

from __future__ import annotations

import tomllib
from pathlib import Path


def read_toml(path: Path, what: str, error: type[Exception]) -> tuple[dict, str]:
    """The table and the text of the TOML file ``path``.

    Raises ``error`` with one line naming ``what`` (e.g. "config file") and the path when the file is
    missing, a directory, not a regular file (a FIFO or a device would block or never end), unreadable,
    not UTF-8, empty or not TOML.
    """
    if not path.exists():
        raise error(f"{what} {path} does not exist")
    if path.is_dir():
        raise error(f"{what} {path} is a directory, not a TOML file")
    if not path.is_file():
        raise error(f"{what} {path} is not a regular file (a FIFO or device?)")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} {path} cannot be read: {exc}") from None
    if not text.strip():
        raise error(f"{what} {path} is empty")
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None
