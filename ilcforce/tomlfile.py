"""Reading a user's TOML file (an experiment or a study) with one clear line for every way it can fail."""

from __future__ import annotations

import tomllib
from pathlib import Path

#: Largest experiment or study file read (bytes). The shipped ones are under 2 kB; a study listing a
#: thousand named settings is a few hundred kB. A bigger file is a mistake (a store or a log given
#: as TOML), and reading it whole would cost time and memory without bound (a 3 GB file: 21 s, 6 GB).
MAX_TOML_BYTES = 4 * 1024 * 1024

def parse_toml(text: str) -> dict:
    """``tomllib.loads``; every refusal raised as ``tomllib.TOMLDecodeError`` with a one-line reason
    (tomllib itself lets an integer over 4300 digits escape as ValueError, Python's int-string limit,
    and nesting deeper than the recursion limit as RecursionError)."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        raise
    except ValueError as exc:
        raise tomllib.TOMLDecodeError(" ".join(str(exc).split())[:200]) from None
    except RecursionError:
        raise tomllib.TOMLDecodeError("arrays or tables nested too deeply") from None


def read_toml(path: Path, what: str, error: type[Exception]) -> tuple[dict, str]:
    """The table and the text of the TOML file ``path``.

    Raises ``error`` with one line naming ``what`` (e.g. "config file") and the path when the file is
    missing (or a symlink that leads nowhere), a directory, not a regular file (a FIFO or a device
    would block or never end), larger than :data:`MAX_TOML_BYTES`, unreadable, not UTF-8, empty or
    not TOML.
    """
    if not path.exists():
        if path.is_symlink():
            raise error(f"{what} {path} is a symbolic link that leads nowhere (dangling or a loop)")
        raise error(f"{what} {path} does not exist")
    if path.is_dir():
        raise error(f"{what} {path} is a directory, not a TOML file")
    if not path.is_file():
        raise error(f"{what} {path} is not a regular file (a FIFO or device?)")
    try:
        with path.open("rb") as handle:
            raw = handle.read(MAX_TOML_BYTES + 1)
    except OSError as exc:
        raise error(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    if len(raw) > MAX_TOML_BYTES:
        raise error(f"{what} {path} is larger than {MAX_TOML_BYTES // (1024 * 1024)} MB: not an experiment "
                    f"or study file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} cannot be read: it is not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    if not text.strip():
        raise error(f"{what} {path} is empty")
    try:
        return parse_toml(text), text
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None
