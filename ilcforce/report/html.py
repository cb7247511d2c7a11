"""The report as a small site a reader opens from disk: ``<report>/index.html`` and a page per part.

Built from the Markdown pages the report has just written, and from nothing else, so whatever a
Markdown page says (a section added later included) is on an HTML page too. The pages are found by
following the links of ``index.md`` and ``findings.md`` (in the order the links come), converted with
markdown-it (installed with rich), and put on HTML pages, one per part of the report:

* the front page ``index.html``: the findings (summary first), the paper's Table 2 and Table 3
  beside ours when the paper's experiment was reported, and the index of every run;
* one page per study (``studies/<name>/index.html``: its report and findings), per experiment
  (``<experiment>/index.html``: its report, tables, claims), per tuning (``tuning/<name>/index.html``)
  and one for the long runs of ``make long`` (``long-run/long-runs.html``: the pages of
  :data:`LONG_RUN_PAGES`; the folder may also be the experiment ``long-run``'s).

Every page carries the same navigation (every page of the site by group, this one's sections under
it), the same few lines of style and the same small script (every table sorts by a click on a
column's header); wide tables wrap their cells to the page's width instead of scrolling sideways
(between words; inside words too for a table still too wide, which the script squeezes). A
link to a Markdown page becomes a link to its section on the HTML page that holds it; figures are
``<img>`` elements pointing at the PNG files by relative path (no network, no CDN, and the pages stay
small); provenance (a ``Provenance`` section, a long block of TOML) is folded in ``<details>``.

Nothing outside the report folder is read into the page or shown by it: every reference a page
makes (a link followed to another page, an image) goes through :func:`ilcforce.report.links.local_target`, which
decodes it, resolves it (symlinks included) and keeps it only when it lands inside the report
folder. A description's text is the user's, so it can name anything (``/home/me/notes.md``,
``~/x.md``, ``file:`` URLs, ``%2e%2e/``, backslashes, a symlink out): such a link stays the
reader's words without being followed, and such an image (a remote one included: the page is
offline) is said in words, never an ``<img>``.
"""

from __future__ import annotations

import html
import posixpath
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from markdown_it import MarkdownIt

from ilcforce.report.figure_files import write_text_whole
from ilcforce.report.links import linked_pages, resolver, url

#: The front page, written beside index.md; every other HTML page is ``<folder>/index.html``.
HTML_NAME = "index.html"
#: make long's pages as the report holds them (``ilcforce.report.long_run``), and their HTML page: the
#: folder is shared with a run of the experiment ``long-run``, whose page is ``long-run/index.html``.
LONG_RUN_PAGES = ("long-run/long-run.md", "long-run/growth-heldout.md", "long-run/growth-fresh.md",
                  "long-run/growth-third.md", "long-run/growth-fourth.md", "long-run/equal-chattering-long.md",
                  "long-run/c3-robust-ablation.md")  # in the order shown
LONG_RUN_UNIT = "long runs"
LONG_RUN_HTML = "long-run/long-runs.html"
#: A fenced block longer than this many lines is folded (configurations as stored run to 150 lines).
FOLD_LINES = 15
#: Headings whose section is folded whole (what a reader needs only to reproduce a run).
FOLDED_HEADINGS = re.compile(r"\b(provenance|command lines?|configuration)\b", re.IGNORECASE)
#: The navigation's groups, in order: a page's group is read from its folder.
GROUPS = (("summary", "Summary"), ("studies", "Studies"), ("experiments", "Experiments"), ("tuning", "Tuning"),
          ("long-run", "Long runs"))
#: The experiment whose Table 2 and Table 3 the summary shows beside the paper's (its setup).
PAPER_EXPERIMENT = "paper"

#: A table column's alignment (markdown-it writes it as a style on every cell) as a class of the style.
_ALIGN = {"right": "r", "center": "c"}
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_FENCE = re.compile(r"^(```+|~~~+)")
#: The URLs a link may keep (a reader follows them by a click; the page never loads them).
_FOLLOWED_SCHEMES = ("http:", "https:", "mailto:")

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 0; color: #1b1b1b; line-height: 1.45; }
nav { position: fixed; top: 0; left: 0; bottom: 0; width: 17rem; overflow-y: auto; padding: 1rem; background: #f4f5f7;
      border-right: 1px solid #ddd; font-size: 0.85rem; box-sizing: border-box; }
nav h2 { font-size: 0.95rem; margin: 1rem 0 0.3rem; } nav ul { list-style: none; padding-left: 0.6rem; margin: 0; }
nav a { text-decoration: none; color: #0b57a4; } nav a:hover { text-decoration: underline; }
nav li.current > a { font-weight: bold; color: #1b1b1b; } nav li.current ul { padding-left: 0.8rem; margin: 0.2rem 0; }
main { margin-left: 17rem; padding: 1rem 2rem 4rem; max-width: 78rem; box-sizing: border-box; }
section.page { border-top: 1px solid #ccc; margin-top: 2rem; padding-top: 0.5rem; }
.source { color: #777; font-size: 0.8rem; font-family: monospace; }
h1.group { font-size: 1.9rem; margin-top: 3rem; border-bottom: 3px solid #0b57a4; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.85rem; max-width: 100%; }
th, td { border: 1px solid #ccc; padding: 0.2rem 0.4rem; vertical-align: top; overflow-wrap: break-word; }
table.squeezed { font-size: 0.75rem; } table.squeezed th, table.squeezed-more td { overflow-wrap: anywhere; }
th { background: #eef1f5; cursor: pointer; user-select: none; text-align: left; }
th.r, td.r { text-align: right; } th.c, td.c { text-align: center; }
th[data-dir="asc"]::after { content: " \\25B2"; } th[data-dir="desc"]::after { content: " \\25BC"; }
tr:nth-child(even) td { background: #fafafa; }
img { max-width: 100%; height: auto; border: 1px solid #eee; margin: 0.5rem 0; }
pre { background: #f6f8fa; padding: 0.6rem; overflow-x: auto; font-size: 0.8rem; }
details { margin: 0.6rem 0; border: 1px solid #e2e2e2; padding: 0.3rem 0.6rem; background: #fcfcfc; }
summary { cursor: pointer; color: #444; }
.missing { color: #a00; font-style: italic; }
"""

# Click a column's header to sort the table's rows by it (numbers as numbers, where every filled
# cell of the column starts with one; a dash or "n/a" sorts last); click again to reverse. A table
# still wider than the page once its cells wrap between words (a long setting name, many columns)
# is squeezed: a smaller font, and its headers may wrap inside a word (its cells too, if it is still
# too wide).
_SCRIPT = """
(function () {
  function wide(table) { return table.offsetWidth > table.parentNode.clientWidth + 1; }
  function squeeze() {  // every width read first, then the classes set: a layout per step, not per table
    var tables = Array.prototype.slice.call(document.querySelectorAll("table"));
    tables.forEach(function (table) { table.classList.remove("squeezed", "squeezed-more"); });
    tables = tables.filter(wide);
    tables.forEach(function (table) { table.classList.add("squeezed"); });
    tables.filter(wide).forEach(function (table) { table.classList.add("squeezed-more"); });
  }
  squeeze();
  window.addEventListener("resize", squeeze);
  function number(text) {
    var m = text.replace(/\\u2212/g, "-").replace(/,/g, "").trim().match(/^[-+]?(\\d+\\.?\\d*|\\.\\d+)(e[-+]?\\d+)?/i);
    return m ? parseFloat(m[0]) : null;
  }
  function sortBy(table, column, header) {
    var body = table.tBodies[0];
    if (!body) return;
    var rows = Array.prototype.slice.call(body.rows);
    var cells = rows.map(function (r) { return r.cells[column] ? r.cells[column].textContent.trim() : ""; });
    var numeric = cells.every(function (c) { return c === "" || c === "-" || c === "\\u2013" || c === "n/a" || number(c) !== null; });
    var dir = header.getAttribute("data-dir") === "asc" ? "desc" : "asc";
    Array.prototype.forEach.call(header.parentNode.cells, function (h) { h.removeAttribute("data-dir"); });
    header.setAttribute("data-dir", dir);
    var keyed = rows.map(function (r, i) { return [cells[i], r, i]; });
    keyed.sort(function (a, b) {
      var x = numeric ? number(a[0]) : a[0], y = numeric ? number(b[0]) : b[0];
      if (x === null || x === "") return y === null || y === "" ? a[2] - b[2] : 1;
      if (y === null || y === "") return -1;
      var order = numeric ? x - y : String(x).localeCompare(String(y), undefined, {numeric: true});
      return (dir === "asc" ? order : -order) || a[2] - b[2];
    });
    keyed.forEach(function (k) { body.appendChild(k[1]); });
  }
  Array.prototype.forEach.call(document.querySelectorAll("table"), function (table) {
    if (!table.tHead) return;
    Array.prototype.forEach.call(table.tHead.rows[0].cells, function (header, column) {
      header.title = "sort by this column";
      header.addEventListener("click", function () { sortBy(table, column, header); });
    });
  });
})();
"""


@dataclass(frozen=True)
class HtmlReport:
    """The pages written, the Markdown pages they hold and what a reader downloads with them."""

    path: Path  # the front page
    pages: tuple[str, ...]
    figures: int
    total_bytes: int  # every HTML page and every figure they show
    site: tuple[Path, ...] = ()  # every HTML page written, the front page first
    largest: tuple[str, int] = ("", 0)  # the largest HTML page (relative to the report) and its bytes

    def size_text(self) -> str:
        front = self.path.stat().st_size if self.path.is_file() else 0
        return (f"{len(self.site)} pages, {self.total_bytes / 1e6:.1f} MB with their {self.figures} figures; "
                f"front page {front / 1e6:.2f} MB, largest {self.largest[0]} {self.largest[1] / 1e6:.2f} MB")


def _anchor(page: str, prefix: str = "p") -> str:
    return f"{prefix}-" + re.sub(r"[^A-Za-z0-9]+", "-", page.removesuffix(".md")).strip("-")


def _markdown() -> MarkdownIt:
    return MarkdownIt("commonmark", {"html": False}).enable("table")


@dataclass(frozen=True)
class _Unit:
    """One HTML page of the site: the Markdown pages it holds, where it is written, its place in the
    navigation."""

    key: str  # "" for the front page, else the folder (or LONG_RUN_UNIT)
    html: str  # its path relative to the report folder
    group: str  # a key of GROUPS
    pages: tuple[str, ...]  # its Markdown pages, each a section, in the order linked

    @property
    def folder(self) -> str:
        return posixpath.dirname(self.html)


def _unit_key(page: str) -> str:
    """Which HTML page a Markdown page is a section of: the front page ("") for the report's own
    pages, a study's or a tuning's folder for theirs, make long's pages together, else the page's
    first folder (an experiment's)."""
    parts = page.split("/")
    if len(parts) == 1:
        return ""
    if page in LONG_RUN_PAGES:
        return LONG_RUN_UNIT
    if parts[0] in ("studies", "tuning") and len(parts) > 2:
        return "/".join(parts[:2])
    return parts[0]


def _unit_html(key: str) -> str:
    if key == "":
        return HTML_NAME
    if key == LONG_RUN_UNIT:
        return LONG_RUN_HTML
    return f"{key}/{HTML_NAME}"


def _unit_group(key: str) -> str:
    if key == "":
        return "summary"
    if key == LONG_RUN_UNIT:
        return "long-run"
    first = key.split("/", 1)[0]
    return first if first in ("studies", "tuning") else "experiments"


def _relative(target: str, folder: str) -> str:
    """A report file's URL from a page in ``folder`` (both relative to the report folder)."""
    return url(posixpath.relpath(target, folder or "."))


def _blocks(text: str) -> list[tuple[str, str]]:
    """The Markdown split into ("text" | "fold", markdown) pieces: a section under a heading that
    :data:`FOLDED_HEADINGS` matches, up to the next heading of its level or higher, and a fenced
    block longer than :data:`FOLD_LINES` lines are folded."""
    pieces: list[tuple[str, str]] = []
    current: list[str] = []
    folded_level = 0  # the level of the heading whose section is being folded (0: none)
    fence: str | None = None
    fence_lines: list[str] = []

    def flush(kind: str, lines: list[str]) -> None:
        if lines:
            pieces.append((kind, "\n".join(lines)))

    for line in text.split("\n"):
        if fence is not None:  # inside a fenced block: only its closing fence ends it
            fence_lines.append(line)
            if line.strip().startswith(fence) and line.strip() == fence[0] * len(line.strip()):
                if folded_level or len(fence_lines) - 2 <= FOLD_LINES:
                    current += fence_lines
                else:
                    flush("text", current)
                    current = []
                    flush("fold", fence_lines)
                fence, fence_lines = None, []
            continue
        opening = _FENCE.match(line.strip())
        if opening:
            fence, fence_lines = opening.group(1), [line]
            continue
        heading = _HEADING.match(line)
        if heading:
            level = len(heading.group(1))
            if folded_level and level <= folded_level:
                flush("fold", current)
                current, folded_level = [], 0
            if not folded_level and FOLDED_HEADINGS.search(heading.group(2)):
                flush("text", current)
                current, folded_level = [], level
        current.append(line)
    current += fence_lines  # an unclosed fence: kept as written
    flush("fold" if folded_level else "text", current)
    return pieces


class _Converter:
    """Markdown pages of one report folder to HTML fragments with links and figures rewritten for the
    HTML page (:class:`_Unit`) they are put on."""

    def __init__(self, out_dir: Path, units: list[_Unit], resolve: Callable[[str, str], str | None]):
        self.out_dir = out_dir
        self.resolve = resolve  # local_target in out_dir
        self.unit_of = {page: unit for unit in units for page in unit.pages if unit.key == _unit_key(page)}
        self.front = {page for unit in units if unit.key == "" for page in unit.pages}  # on the front page too
        self.md = _markdown()
        self.figures: set[str] = set()  # every figure shown, relative to out_dir
        self.current: _Unit = units[0]

    def _page_link(self, target: str) -> str:
        """Where a link to the Markdown page ``target`` goes: its section, on this HTML page when it is a
        section of it, else on the HTML page that holds it."""
        if target in self.current.pages:
            return "#" + _anchor(target, "summary" if self.current.key == "" and _unit_key(target) else "p")
        unit = self.unit_of[target]
        return _relative(unit.html, self.current.folder) + "#" + _anchor(target)

    def _link(self, folder: str, href: str) -> str | None:
        """A link's rewritten target: a page of this report becomes its section (on this HTML page or
        another), a file of the report its path relative to this HTML page; a URL of a scheme the
        reader follows (``https:``, ``mailto:``) and a fragment stay as written; None (the link is
        dropped, its words kept) for a path that does not name a file of the report
        (:func:`ilcforce.report.links.local_target`), or names none written (a folder included)."""
        if href.startswith("#"):
            return href
        target = self.resolve(folder, href)
        if target is None:
            return href if href.lower().startswith(_FOLLOWED_SCHEMES) else None
        if target in self.unit_of:
            return self._page_link(target)
        if not (self.out_dir / target).is_file():
            return None  # a dead link (or a folder, which is no page of the site): its words only
        return _relative(target, self.current.folder)

    def render(self, page: str, text: str) -> str:
        folder = posixpath.dirname(page)
        tokens = self.md.parse(text)
        dropped: set[int] = set()  # the link_open tokens whose closing token goes too
        for token in tokens:
            if token.type in ("th_open", "td_open") and token.attrGet("style"):
                # a cell's alignment as a class of the page's style, not an attribute on every cell: the
                # attribute was 40% of a large study's page (left is the style's default)
                align = str(token.attrGet("style")).removeprefix("text-align:")
                token.attrs.pop("style")
                if align in _ALIGN:
                    token.attrSet("class", _ALIGN[align])
            children = token.children or []
            for child in children:
                if child.type == "link_open":
                    href = self._link(folder, str(child.attrGet("href") or ""))
                    if href is None:
                        dropped.add(child.level)
                        child.type, child.tag, child.attrs, child.nesting = "text", "", {}, 0
                    else:
                        child.attrSet("href", href)
                elif child.type == "link_close" and child.level in dropped:
                    dropped.discard(child.level)
                    child.type, child.tag, child.nesting = "text", "", 0
                elif child.type == "image":
                    src = str(child.attrGet("src") or "")
                    target = self.resolve(folder, src)
                    alt = child.content
                    if target is not None and (self.out_dir / target).is_file():
                        child.attrSet("src", _relative(target, self.current.folder))
                        child.attrSet("loading", "lazy")
                        self.figures.add(target)
                    else:  # said in words: a broken image tells the reader nothing, a remote one
                        # would be fetched by an offline page, a path outside would show what the
                        # report must not
                        why = ("figure not written" if target is not None else
                               "image not shown: not a file of this report")
                        child.type, child.tag, child.attrs, child.children = "text", "", {}, None
                        child.content = (f"[{why}: {target}]" if target is not None else
                                         f"[{why}{': ' + alt if alt else ''}]")
        return self.md.renderer.render(tokens, self.md.options, {})

    def page(self, page: str, anchor: str) -> str:
        text = (self.out_dir / page).read_text(encoding="utf-8")
        parts = []
        for kind, markdown in _blocks(text):
            body = self.render(page, markdown)
            if kind == "fold":
                first = markdown.strip().split("\n", 1)[0]
                heading = _HEADING.match(first)
                label = heading.group(2) if heading else (
                    f"{first.strip('`~ ') or 'text'} block, {markdown.count(chr(10)) - 1} lines")
                body = f"<details><summary>{html.escape(label)}</summary>\n{body}</details>"
            parts.append(body)
        return (f'<section class="page" id="{anchor}">\n<div class="source">{html.escape(page)}</div>\n'
                + "\n".join(parts) + "</section>\n")


def _title(out_dir: Path, page: str) -> str:
    """The page's first heading, with its file named where that alone would not tell two pages
    apart (a study's report and its findings page)."""
    stem = posixpath.basename(page).removesuffix(".md")
    for line in (out_dir / page).read_text(encoding="utf-8").split("\n"):
        heading = _HEADING.match(line)
        if heading:
            title = re.sub(r"[`*_]", "", heading.group(2))
            return f"{title} ({stem})" if stem in ("findings",) else title
    return stem.replace("_", " ").capitalize()


def _units(out_dir: Path, pages: list[str], summary_extra: list[str]) -> list[_Unit]:
    """The site's HTML pages, in the navigation's order: the front page, then per group each page in
    the order its folder was first linked."""
    keys = list(dict.fromkeys(_unit_key(page) for page in pages))
    if "" not in keys:
        keys.insert(0, "")
    members: dict[str, list[str]] = {key: [] for key in keys}
    for page in pages:
        members[_unit_key(page)].append(page)
    # the front page: the findings, the paper's Tables 2 and 3 beside ours, then the index of every run
    front = members[""]
    members[""] = [p for p in front if p == "findings.md"] + summary_extra + [p for p in front if p != "findings.md"]
    order = [key for key, _ in GROUPS]
    keys.sort(key=lambda key: order.index(_unit_group(key)))  # stable: each group in the order linked
    # a folder's pages together, in the order their folders were first linked (a study's subfolders),
    # led by the part's own page (its report; a tuning's index) however the findings linked the rest
    for key in keys[1:]:  # keys[0] is the front page (the summary group leads), its order set above
        folders = list(dict.fromkeys(posixpath.dirname(p) for p in members[key]))
        members[key].sort(key=lambda p: folders.index(posixpath.dirname(p)))
        if key == LONG_RUN_UNIT:
            members[key].sort(key=LONG_RUN_PAGES.index)
        else:
            leading = [p for p in (f"{key}/report.md", f"{key}/index.md") if p in members[key]][:1]
            members[key] = leading + [p for p in members[key] if p not in leading]
    return [_Unit(key=key, html=_unit_html(key), group=_unit_group(key), pages=tuple(members[key]))
            for key in keys if members[key]]


def _navigation(titles: dict[str, str], units: list[_Unit], current: _Unit) -> list[str]:
    """The navigation every page carries: every HTML page of the site by group, this one marked
    and its sections listed under it."""
    lines = ['<div class="brand"><strong>ilcforce report</strong></div>']
    for key, title in GROUPS:
        mine = [unit for unit in units if unit.group == key]
        if not mine:
            continue
        lines.append(f"<h2>{title}</h2><ul>")
        for unit in mine:
            href = html.escape(_relative(unit.html, current.folder), quote=True)
            name = ("Front page: summary and findings" if unit.key == "" else
                    titles[unit.pages[0]].removeprefix("ilcforce report: "))
            if unit is not current:
                lines.append(f'<li><a href="{href}">{html.escape(name)}</a></li>')
                continue
            lines.append(f'<li class="current"><a href="{href}" aria-current="page">{html.escape(name)}</a><ul>')
            for page in unit.pages:
                anchor = _anchor(page, "summary" if unit.key == "" and _unit_key(page) else "p")
                lines.append(f'<li><a href="#{anchor}">{html.escape(titles[page])}</a></li>')
            lines.append("</ul></li>")
        lines.append("</ul>")
    return lines


def _document(title: str, nav: list[str], body: list[str]) -> str:
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title>", f"<style>{_STYLE}</style>", "</head>", "<body>",
        "<nav>", *nav, "</nav>", "<main>", *body, "</main>",
        f"<script>{_SCRIPT}</script>", "</body>", "</html>", ""])


def write_html(out_dir: Path) -> HtmlReport | None:
    """Write the report's HTML pages (the front page ``out_dir/index.html`` and one page per study,
    experiment, tuning and the long runs; see the module's docstring) from the Markdown pages under
    ``out_dir``; None, and nothing written, when ``out_dir`` holds neither index.md nor findings.md."""
    out_dir = Path(out_dir)
    resolve = resolver(out_dir)
    pages = linked_pages(out_dir, ["findings.md", "index.md"], resolve)
    if not pages:
        return None
    summary_extra = [p for p in (f"{PAPER_EXPERIMENT}/table2.md", f"{PAPER_EXPERIMENT}/table3.md")
                     if resolve("", p) == p and (out_dir / p).is_file()]
    units = _units(out_dir, pages, summary_extra)
    converter = _Converter(out_dir, units, resolve)
    titles = {page: _title(out_dir, page) for unit in units for page in unit.pages}  # read once, shown on every page
    written: list[Path] = []
    sizes: dict[str, int] = {}
    for unit in units:
        converter.current = unit
        body = []
        if unit.key == "":
            body.append('<h1 class="group" id="group-summary">Summary</h1>')
        for page in unit.pages:
            anchor = _anchor(page, "summary" if unit.key == "" and _unit_key(page) else "p")
            body.append(converter.page(page, anchor))
        title = "ilcforce report" if unit.key == "" else f"{titles[unit.pages[0]]} - ilcforce report"
        path = out_dir / unit.html
        write_text_whole(path, _document(title, _navigation(titles, units, unit), body))
        written.append(path)
        sizes[unit.html] = path.stat().st_size
    total = sum(sizes.values()) + sum((out_dir / f).stat().st_size for f in converter.figures)
    return HtmlReport(path=out_dir / HTML_NAME, pages=tuple(pages + summary_extra), figures=len(converter.figures),
                      total_bytes=total, site=tuple(written), largest=max(sizes.items(), key=lambda kv: kv[1]))
