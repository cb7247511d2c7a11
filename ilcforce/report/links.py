"""Where a report's pages point, kept inside the report: the one resolver of every link followed and every
image shown (:func:`local_target`), and the scan that finds the pages a report's links reach.

A reference names a file of the report only when, decoded and resolved (symlinks included), it stays inside
the report folder; a URL of any scheme, an absolute, home or network path, a backslash or a path leaving the
folder names nothing. :mod:`ilcforce.report.html` builds the pages on these; nothing else decides what a
page may read.
"""

from __future__ import annotations

import functools
import posixpath
import re
import urllib.parse
from collections.abc import Callable
from pathlib import Path

#: A URL's scheme (``https:``, ``file:``, ``data:``, a drive letter ``C:``)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def local_target(out_dir: Path, folder: str, href: str) -> str | None:
    """The file a page's reference ``href`` names, as a POSIX path relative to ``out_dir``, or None
    when it names anything else: a URL of any scheme (``https:``, ``file:``, ``data:``), a
    network path (``//host``), an absolute or home path (``/``, ``~``, ``C:``), a backslash, a
    control character, or a path that leaves ``out_dir`` (``..``, percent-encoded or not, or a
    symlink whose target is outside). ``folder`` is the referring page's folder relative to
    ``out_dir``. The reference is decoded first (markdown-it percent-encodes what it parses) and the
    checks run on the decoded path, so no encoding slips past them; the final check is on the
    resolved path, so no spelling does."""
    try:
        path = urllib.parse.unquote(href.partition("#")[0].partition("?")[0], errors="strict") if href else ""
    except UnicodeDecodeError:  # an encoded byte sequence that is no text names no file of the report
        return None
    if (not path or SCHEME.match(path) or SCHEME.match(href) or path.startswith(("/", "~"))
            or "\\" in path or not path.isprintable()):
        return None
    relative = posixpath.normpath(posixpath.join(folder, path))
    if relative == ".." or relative.startswith(("../", "/")):
        return None
    root = Path(out_dir).resolve()
    try:
        real = (root / relative).resolve()
    except (OSError, RuntimeError):  # a symlink loop, a name the system refuses
        return None
    return relative if real == root or real.is_relative_to(root) else None


def url(relative: str) -> str:
    """A report file's path as a relative URL (a space or '#' in a name is encoded; '/', '=', ',' and
    '+', which variant folders hold, are kept readable)."""
    return urllib.parse.quote(relative, safe="/=,+")


#: Where a page names another: an inline link's destination (``](x.md)``, ``](<x.md>)``) or a reference
#: definition's (``[r]: x.md``). Broad on purpose: whatever it finds is followed only through
#: :func:`local_target`, so a form it catches that Markdown would not read as a link costs nothing;
#: and scanning costs little where parsing every page a second time did not (a 2 MB page of tables:
#: 9 s to parse, 0.1 s to scan).
_DESTINATION = re.compile(r"\]\(\s*(?:<([^<>\n]+)>|([^)\s<>]+))|^ {0,3}\[[^\]]+\]:[ \t]*(?:<([^<>\n]+)>|(\S+))",
                          re.MULTILINE)


def resolver(out_dir: Path) -> Callable[[str, str], str | None]:
    """:func:`local_target` in ``out_dir``, each (folder, reference) resolved once per page built (a
    report's tables repeat their links; a resolution costs a few system calls)."""
    return functools.lru_cache(maxsize=None)(functools.partial(local_target, Path(out_dir)))


def linked_pages(out_dir: Path, start: list[str], resolve: Callable[[str, str], str | None]) -> list[str]:
    """Every Markdown page reachable from ``start`` by links that stay inside ``out_dir``
    (``resolve``: :func:`local_target` there), in the order first linked."""
    seen: list[str] = []
    queue = [p for p in start if resolve("", p) == p and (out_dir / p).is_file()]
    while queue:
        page = queue.pop(0)
        if page in seen:
            continue
        seen.append(page)
        folder = posixpath.dirname(page)
        for destination in _DESTINATION.findall((out_dir / page).read_text(encoding="utf-8")):
            linked = resolve(folder, "".join(destination))  # the one group that matched
            if (linked is not None and linked.endswith(".md") and linked not in seen
                    and (out_dir / linked).is_file()):
                queue.append(linked)
    return seen
