"""Reading a user's TOML file (an experiment or a study) with one clear line for every way it can fail;
finding a shipped experiment file by its name (``-c serial2r``); writing a configuration back as TOML
(``ilcforce config``).

:func:`read_regular` is the one safe open of ilcforce for every file a command is given or finds
(experiment, study and tuning files, a tuning store's ``tuned.toml``, model files and every file they
name): whatever sits at the name, it returns the bytes of a regular file of bounded size or one line
saying why not, in bounded time (a FIFO, a device, a socket or a folder is never read or waited on).
The stores' own records are read by the same rules (:func:`ilcforce.store.records.read_json`).
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tomllib
from pathlib import Path

#: Largest experiment or study file read (bytes). The shipped ones are under 2 kB; a study listing a
#: thousand named settings is a few hundred kB. A bigger file is a mistake (a store or a log given
#: as TOML), and reading it whole would cost time and memory without bound (a 3 GB file: 21 s, 6 GB).
MAX_TOML_BYTES = 4 * 1024 * 1024
#: Deepest nesting of tables and arrays read. A configuration is 3 deep, a study file 4; a header
#: 500 tables deep parsed (tomllib builds it without recursion) and then broke every recursive walk
#: of the result with a RecursionError traceback.
MAX_TOML_DEPTH = 32


class UnreadableFile(Exception):
    """Why :func:`read_regular` refused a file: the message completes a sentence that starts with the
    file's name ("is a FIFO (named pipe), not a regular file")."""


def _kind(mode: int) -> str:
    """What a file that is not a regular one is, as the end of a sentence."""
    if stat.S_ISDIR(mode):
        return "is a directory"
    if stat.S_ISLNK(mode):
        return "is a symbolic link"
    kinds = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))
    return f"is {next((what for test, what in kinds if test(mode)), 'a special file')}, not a regular file"


def check_regular(path: Path | str, limit: int, *, follow_links: bool = True) -> os.stat_result:
    """The stat of ``path`` if it is a regular file of at most ``limit`` bytes (by name, without opening
    it: for a file another library opens, such as a mesh MuJoCo reads); :class:`UnreadableFile` as
    :func:`read_regular` says otherwise."""
    name = os.fspath(path)
    try:
        info = os.stat(name) if follow_links else os.lstat(name)
    except FileNotFoundError:
        if os.path.islink(name):
            raise UnreadableFile("is a symbolic link that leads nowhere (dangling or a loop)") from None
        raise UnreadableFile("does not exist") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnreadableFile("is a symbolic link that leads nowhere (dangling or a loop)") from None
        if exc.errno == errno.ENOTDIR:
            raise UnreadableFile("does not exist (a part of its path is not a folder)") from None
        raise UnreadableFile(f"cannot be read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise UnreadableFile(_kind(info.st_mode))
    if info.st_size > limit:
        raise UnreadableFile(f"is larger than {_size(limit)}")
    return info


def read_regular(path: Path | str, limit: int, *, follow_links: bool = True) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them; :class:`UnreadableFile` saying
    why not: missing, a dangling or looping link, a link at all when not ``follow_links`` (the
    file's own name must hold it: a store's files), a directory, a FIFO, a socket or a device, more
    than ``limit`` bytes, or unreadable.

    The kind is checked twice: by name before opening (:func:`check_regular`: nothing but a regular
    file is ever opened), and on the opened descriptor (a name swapped between the two checks). The
    open is non-blocking, so a FIFO put there meanwhile cannot hold the process, and never follows a
    last link when ``follow_links`` is false; at most ``limit + 1`` bytes are read, so a file that
    grows meanwhile (or a link to /dev/zero made meanwhile) cannot exhaust memory."""
    name = os.fspath(path)
    check_regular(name, limit, follow_links=follow_links)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow_links else os.O_NOFOLLOW)
    try:
        fd = os.open(name, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow_links:
            raise UnreadableFile("is a symbolic link") from None
        if exc.errno == errno.ENXIO:  # a socket, put there after the check
            raise UnreadableFile("is a socket, not a regular file") from None
        raise UnreadableFile(f"cannot be read: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):  # replaced between the check and the open
            raise UnreadableFile(_kind(mode))
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(limit + 1 - size, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise UnreadableFile(f"cannot be read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if size > limit:  # it grew meanwhile
        raise UnreadableFile(f"is larger than {_size(limit)}")
    return b"".join(chunks)


def _size(limit: int) -> str:
    """``limit`` bytes in words ("4 MB", "16 kB", "900 bytes")."""
    for unit, scale in (("GB", 1 << 30), ("MB", 1 << 20), ("kB", 1 << 10)):
        if limit >= scale and limit % scale == 0:
            return f"{limit // scale} {unit}"
    return f"{limit} bytes"


def shipped_folder() -> Path | None:
    """The folder of the shipped experiment files: inside the installed package (a wheel installs
    them as ``ilcforce/experiments/``), else the source checkout's ``experiments/`` beside the
    package (a clone, or an editable install); None when neither exists."""
    package = Path(__file__).resolve().parent
    for folder in (package / "experiments", package.parent / "experiments"):
        if folder.is_dir():
            return folder
    return None


def shipped_names() -> list[str]:
    """The names of the shipped experiment and study files (``paper``, ``serial2r``, ...), sorted."""
    folder = shipped_folder()
    return sorted(p.stem for p in folder.glob("*.toml")) if folder is not None else []


def resolve_toml(path: Path | str) -> Path:
    """``path`` itself when it exists or names a folder; else, when it is a bare name (no folder)
    of a shipped file (``serial2r`` or ``serial2r.toml``; ``serial2r-tune`` in ``tuning/``), that shipped file; else ``path``
    unchanged, so the reader names what the user wrote."""
    path = Path(path)
    if path.exists() or path.is_symlink() or len(path.parts) != 1:
        return path
    folder = shipped_folder()
    if folder is None:
        return path
    name = path.name if path.suffix == ".toml" else f"{path.name}.toml"
    for candidate in (folder / name, folder / "tuning" / name):  # tuning files keep a folder of their own
        if candidate.is_file():
            return candidate
    return path


def _depth(node) -> int:
    """How deep tables and arrays nest in ``node`` (0 for a scalar), without recursion."""
    deepest, stack = 0, [(node, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            items = item.values()
        elif isinstance(item, list):
            items = item
        else:
            continue
        depth += 1
        deepest = max(deepest, depth)
        if depth <= MAX_TOML_DEPTH:
            stack.extend((child, depth) for child in items)
    return deepest


def parse_toml(text: str) -> dict:
    """``tomllib.loads``; every refusal raised as ``tomllib.TOMLDecodeError`` with a one-line reason
    (tomllib itself lets an integer over 4300 digits escape as ValueError, Python's int-string limit,
    and nesting deeper than the recursion limit as RecursionError); tables or arrays nested deeper
    than :data:`MAX_TOML_DEPTH` are refused too."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        raise
    except ValueError as exc:
        raise tomllib.TOMLDecodeError(" ".join(str(exc).split())[:200]) from None
    except RecursionError:
        raise tomllib.TOMLDecodeError("arrays or tables nested too deeply") from None
    if _depth(table) > MAX_TOML_DEPTH:
        raise tomllib.TOMLDecodeError(f"tables or arrays nested more than {MAX_TOML_DEPTH} deep")
    return table


def read_toml(path: Path, what: str, error: type[Exception]) -> tuple[dict, str]:
    """The table and the text of the TOML file ``path``.

    Raises ``error`` with one line naming ``what`` (e.g. "config file") and the path when the file is
    missing (or a symlink that leads nowhere), a directory, not a regular file (a FIFO or a device
    would block or never end), larger than :data:`MAX_TOML_BYTES`, unreadable, not UTF-8, empty or
    not TOML.
    """
    try:
        raw = read_regular(path, MAX_TOML_BYTES)
    except UnreadableFile as exc:
        reason = str(exc)
        if reason == "does not exist":
            names = shipped_names() if len(path.parts) == 1 else []
            reason += f" (shipped experiments, usable by name: {', '.join(names)})" if names else ""
        elif reason == "is a directory":
            reason += ", not a TOML file"
        elif reason.startswith("is larger than"):
            reason += ": not an experiment or study file"
        raise error(f"{what} {path} {reason}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} cannot be read: it is not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    if text.startswith("\ufeff"):  # tomllib says only "Invalid statement (line 1, col 1)"
        raise error(f"{what} {path} starts with a UTF-8 byte-order mark (BOM), which TOML does not allow; "
                    "save it as UTF-8 without BOM")
    if not text.strip():
        raise error(f"{what} {path} is empty")
    try:
        return parse_toml(text), text
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None


def _escape(char: str) -> str:
    code = ord(char)
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"


def _toml_string(text: str) -> str:
    """A TOML basic string in ASCII: TOML's own escapes for quotes, backslashes, control and non-ASCII
    characters (JSON's would split a character beyond U+FFFF into two surrogate halves, which TOML
    refuses), so the text survives any terminal encoding and loads back equal."""
    short = {'"': '\\"', "\\": "\\\\", "\n": "\\n", "\t": "\\t", "\r": "\\r"}
    return '"' + "".join(short.get(c) or (c if " " <= c <= "~" else _escape(c)) for c in text) + '"'


def toml_comment(text: str) -> str:
    """``text`` as one ASCII TOML comment line: control and non-ASCII characters escaped."""
    return "# " + "".join(c if " " <= c <= "~" else _escape(c) for c in text)


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_string(key)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)  # floats round-trip exactly; inf and nan are TOML too
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {type(value).__name__} {value!r}")


def dump_toml(data: dict, comments: dict[str, str] | None = None) -> str:
    """TOML text of nested tables of scalars and lists (what a configuration holds), every table
    written out (``[a.b]``) so that each key reads as the dotted name ``--set`` takes; ``comments``
    maps a table's dotted name to a comment line above it. ``parse_toml`` reads it back equal."""
    lines: list[str] = []

    def table(node: dict, name: str) -> None:
        scalars = {k: v for k, v in node.items() if not isinstance(v, dict)}
        if name and (scalars or not node):
            if lines:
                lines.append("")
            if comments and name in comments:
                lines.append(toml_comment(comments[name]))
            lines.append(f"[{name}]")
        lines.extend(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in scalars.items())
        for key, value in node.items():
            if isinstance(value, dict):
                table(value, f"{name}.{_toml_key(key)}" if name else _toml_key(key))

    table(data, "")
    return "\n".join(lines) + "\n"
