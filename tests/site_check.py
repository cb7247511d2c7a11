"""Every page of a generated report, read as a browser would: each ``href`` and ``src`` of every HTML
page either resolves to a file of the report (and a ``#fragment`` to an element of the page it names)
or is a link a reader follows by a click (``http(s):``, ``mailto:``); nothing is loaded from outside
the report (no remote image, stylesheet, script, frame or CSS ``url()``). Used by the report tests."""

from __future__ import annotations

import re
import urllib.parse
from dataclasses import dataclass, field
from html.parser import HTMLParser
from pathlib import Path

#: Attributes that make a browser load something (``href`` of ``<a>`` only on a click).
LOADING = ("src", "srcset", "poster", "data", "background", "action", "formaction")
#: Schemes a reader may follow from a link (never loaded by the page itself).
FOLLOWED = ("http:", "https:", "mailto:")
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: set[str] = set()
        self.references: list[tuple[str, str, str]] = []  # (tag, attribute, value)
        self.styles: list[str] = []
        self._in_style = False

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name in ("id", "name") and value:
                self.ids.add(value)
            if value is not None and (name == "href" or name in LOADING):
                self.references.append((tag, name, value))
            if name == "style" and value:
                self.styles.append(value)
        self._in_style = tag == "style"

    def handle_endtag(self, tag):
        self._in_style = False

    def handle_data(self, data):
        if self._in_style:
            self.styles.append(data)


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    page.close()
    return page


@dataclass
class Site:
    """What :func:`check_site` read: the pages, how many references of each kind, and every problem."""

    pages: list[Path] = field(default_factory=list)
    local_links: int = 0  # links to a file of the report (a page or a table)
    cross_page_links: int = 0  # links to a section of another HTML page
    images: int = 0
    problems: list[str] = field(default_factory=list)


def check_site(out_dir: Path) -> Site:
    out_dir = Path(out_dir)
    root = out_dir.resolve()
    site = Site(pages=sorted(out_dir.rglob("*.html")))
    parsed = {path.resolve(): _parse(path) for path in site.pages}
    for path in site.pages:
        page = parsed[path.resolve()]
        where = path.relative_to(out_dir).as_posix()
        for css in page.styles:
            if re.search(r"url\s*\(|@import", css, re.IGNORECASE):
                site.problems.append(f"{where}: CSS loads a resource: {css.strip()[:80]!r}")
        for tag, attribute, value in page.references:
            said = f"{where}: <{tag} {attribute}={value!r}>"
            if tag != "a" and attribute == "href" and tag not in ("area",):
                site.problems.append(f"{said}: a <{tag}> loads what it names (a stylesheet, an icon)")
                continue
            if value.startswith("#"):
                if value[1:] not in page.ids:
                    site.problems.append(f"{said}: no element of this page has that id")
                continue
            if value.startswith("//") or (_SCHEME.match(value) and (attribute != "href"
                                                                     or not value.lower().startswith(FOLLOWED))):
                site.problems.append(f"{said}: not a file of the report (remote or another scheme)")
                continue
            if _SCHEME.match(value):  # an http(s)/mailto link the reader follows
                continue
            address, _, fragment = value.partition("#")
            target = (path.parent / urllib.parse.unquote(address.partition("?")[0])).resolve()
            if not target.is_relative_to(root):
                site.problems.append(f"{said}: outside the report")
            elif not target.is_file():
                site.problems.append(f"{said}: no such file in the report")
            elif fragment and target.suffix == ".html":
                if fragment not in parsed[target].ids:
                    site.problems.append(f"{said}: {target.name} has no element with id {fragment!r}")
            if tag == "img":
                site.images += 1
            else:
                site.local_links += 1
                site.cross_page_links += target.suffix == ".html" and target != path.resolve()
    return site


def dead_markdown_links(out_dir: Path) -> tuple[int, list[str]]:
    """Every link and image of every Markdown page of the report, as a Markdown viewer follows them:
    (how many name a file by a relative path, and those whose file the report does not hold). The
    HTML pages keep a dead link's words only, so a check of the HTML alone would not see one."""
    from markdown_it import MarkdownIt

    out_dir = Path(out_dir)
    root = out_dir.resolve()
    parser = MarkdownIt("commonmark").enable("table")

    def tokens(items):
        for token in items:
            yield token
            yield from tokens(token.children or [])

    checked, dead = 0, []
    for page in sorted(out_dir.rglob("*.md")):
        for token in tokens(parser.parse(page.read_text(encoding="utf-8"))):
            reference = token.attrGet("href") if token.type == "link_open" else (
                token.attrGet("src") if token.type == "image" else None)
            if not reference or reference.startswith("#") or _SCHEME.match(str(reference)):
                continue
            checked += 1
            target = (page.parent / urllib.parse.unquote(str(reference).partition("#")[0])).resolve()
            if not (target.is_relative_to(root) and target.is_file()):
                dead.append(f"{page.relative_to(out_dir).as_posix()}: {reference}")
    return checked, dead
