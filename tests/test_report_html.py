"""The report as a small site (ilcforce/report/html.py): built from the Markdown pages, a front page
and one page per study, experiment, tuning and the long runs, the same navigation on each; links to
a section of the page that holds it; provenance folded; every link and image of every page resolves
inside the report and nothing is loaded from the network; each page small; and, in headless
Chromium, no console error, no broken image, sortable tables, no table wider than the page."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from browser import find_chromium, open_page
from site_check import check_site, dead_markdown_links
from ilcforce.report import html
from ilcforce.report.build import write_report
from test_report import write_store

#: Issue 47 item 5's bounds: the front page, and every other page (each without its figures).
FRONT_PAGE_BYTES = 1_000_000
PAGE_BYTES = 2_000_000


#: A table of a study's kind at its widest (a column per method's divergence, long headers, long cells).
WIDE_TABLE = ("| setting | " + " | ".join(f"H(C1)/H(C3) y settled, method {i} divergence" for i in range(24)) + " |\n"
              + "|:---|" + "---:|" * 24 + "\n"
              + "| noise.scale=0.5,experiment.sample_time=0.0001 | "
              + " | ".join(f"j = {i} [3, 17] ({i} of 20 seeds)" for i in range(24)) + " |\n")


def _write(root: Path, pages: dict[str, str]) -> None:
    for name, text in pages.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)


@pytest.fixture
def pages(tmp_path: Path) -> Path:
    """A report folder of Markdown pages as the reporter lays them out, one of each kind."""
    toml = "\n".join(f"key{i} = {i}" for i in range(40))
    _write(tmp_path, {
        "index.md": "# ilcforce reports\n\n### [mc](studies/mc/report.md)\n\n| experiment |\n|:---|\n"
                    "| [paper](paper/report.md) |\n\n## Tuning\n\n* [t](tuning/t/report.md)\n",
        "findings.md": "Bottom line: claim 1 holds.\n\n[paper's report](paper/report.md#table-2)\n",
        "studies/mc/report.md": "# Study mc\n\n![fig](fig3.png)\n\n[findings](findings.md)\n",
        "studies/mc/findings.md": "# Study mc\n\nfindings\n\n" + WIDE_TABLE,
        "paper/report.md": ("# experiment paper\n\nMethods.\n\n## Provenance\n\n| method | file |\n|:---|:---|\n"
                            "| c3 | c3.h5 |\n\n```toml\n" + toml + "\n```\n\nCommand lines: x\n\n"
                            "## Table 2\n\n[Table 2](table2.md)\n\n![missing](fig9.png)\n\n```toml\n" + toml
                            + "\n```\n"),
        "paper/table2.md": "# Table 2 (paper)\n\n| method | e [m] |\n|:---|---:|\n| c1 | 2e-5 |\n| c3 | 1e-5 |\n",
        "tuning/t/report.md": "# Tuning t\n\ntrials\n",
        "unlinked.md": "# never linked: not on the page\n",
    })
    (tmp_path / "studies" / "mc" / "fig3.png").write_bytes(b"\x89PNG fake")
    return tmp_path


def _page(root: Path, name: str) -> str:
    return (root / name).read_text(encoding="utf-8")


def test_each_part_is_a_page_of_its_own_in_the_reader_s_order(pages: Path) -> None:
    site = html.write_html(pages)
    assert site.path == pages / "index.html"
    assert [p.relative_to(pages).as_posix() for p in site.site] == [
        "index.html", "studies/mc/index.html", "paper/index.html", "tuning/t/index.html"]
    front, study, paper = _page(pages, "index.html"), _page(pages, "studies/mc/index.html"), _page(pages, "paper/index.html")
    everything = "".join(p.read_text() for p in site.site)
    assert "never linked" not in everything  # the Markdown's own links decide what is on the pages
    # the front page: the findings, the index, the paper's Tables 2 and 3; nothing of a study's or a run's report
    order = [front.index(f'id="{anchor}"') for anchor in ("group-summary", "p-findings", "summary-paper-table2", "p-index")]
    assert order == sorted(order)
    assert 'id="p-paper-report"' not in front and 'id="p-studies-mc-report"' not in front
    # a study's page holds its pages in the order linked; an experiment's its report and tables
    assert study.index('id="p-studies-mc-report"') < study.index('id="p-studies-mc-findings"')
    assert paper.index('id="p-paper-report"') < paper.index('id="p-paper-table2"')
    assert 'id="p-tuning-t-report"' in _page(pages, "tuning/t/index.html")
    # a link to a page is a link to its section on the page that holds it (a fragment is dropped)
    assert 'href="paper/index.html#p-paper-report"' in front
    assert 'href="studies/mc/index.html#p-studies-mc-report"' in front
    assert 'href="#p-studies-mc-findings"' in study  # on the same page: its section
    assert 'href="#p-paper-table2"' in paper
    assert not re.search(r'href="[^"#]*\.md', everything), "a link to a Markdown file left on a page"
    # figures by relative path from their page, lazy; a missing one is said in words, never a broken image
    assert 'src="fig3.png"' in study and 'loading="lazy"' in study
    assert "[figure not written: paper/fig9.png]" in paper and "fig9.png\"" not in paper
    assert site.figures == 1
    # a column's alignment is a class of the page's style, not a style attribute on every cell
    assert '<th class="r">e [m]</th>' in paper and '<td class="r">2e-5</td>' in paper and "<td>c1</td>" in paper
    assert not re.search(r"<t[dh][^>]*style=", everything)


def test_every_page_carries_the_same_navigation(pages: Path) -> None:
    """Every page lists every page of the site (by a link relative to itself, each resolving), and marks itself."""
    site = html.write_html(pages)
    listed = []
    for path in site.site:
        nav = re.search(r"<nav>(.*?)</nav>", path.read_text(), re.S).group(1)
        targets = [(path.parent / h).resolve() for h in re.findall(r'href="([^"#]+)', nav)]
        listed.append(targets)
        assert set(targets) == {p.resolve() for p in site.site}, path
        current = re.findall(r'<li class="current"><a href="([^"]+)" aria-current="page">', nav)
        assert [(path.parent / h).resolve() for h in current] == [path.resolve()]
    assert all(targets == listed[0] for targets in listed), "the pages' navigations differ"


def test_provenance_and_long_blocks_are_folded(pages: Path) -> None:
    html.write_html(pages)
    text = _page(pages, "paper/index.html")
    section = text[text.index('id="p-paper-report"'):text.index('id="p-paper-table2"')]
    folds = re.findall(r"<details><summary>(.*?)</summary>(.*?)</details>", section, re.S)
    assert [label for label, _ in folds] == ["Provenance", "toml block, 40 lines"]
    provenance = folds[0][1]
    assert "c3.h5" in provenance and "key39 = 39" in provenance and "Command lines" in provenance
    assert "Table 2" not in provenance  # the fold ends at the next heading of its level
    assert "<h2>Table 2</h2>" in section


def test_nothing_on_the_pages_reaches_the_network(pages: Path) -> None:
    site = html.write_html(pages)
    for path in site.site:
        text = path.read_text()
        assert not re.search(r'(src|href)="(https?:)?//', text)
        assert "<link" not in text and "<script src" not in text and "@import" not in text
    checked = check_site(pages)
    assert checked.problems == [] and checked.images == 1 and checked.cross_page_links > 0


def test_no_markdown_no_page(tmp_path: Path) -> None:
    assert html.write_html(tmp_path) is None
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory):
    """The report of a small synthetic experiment (every run figure drawn) and of a tiny study of real
    runs (2 seeds x 2 methods x 3 iterations of 0.2 s), with the long runs' committed pages."""
    from test_study import small_study

    from ilcforce.study import run_study

    root = tmp_path_factory.mktemp("results")
    for method in ("c1", "c2", "c3"):
        write_store(root / "synthetic" / f"{method}.h5", method)
    run_study(small_study(name="tiny"), root, workers=1)
    return write_report(root, tmp_path_factory.mktemp("report"), formats=("png",))


def test_write_report_writes_a_small_site_whose_every_reference_resolves(report) -> None:
    """Issue 47 item 5: a page per part, each small, and every link and image of every page resolves to
    a file of the report (a fragment to an element of its page); nothing loaded from outside it."""
    out = report.out_dir
    assert report.html is not None and report.html.path == out / "index.html"
    written = {p.relative_to(out).as_posix() for p in report.html.site}
    assert written == {"index.html", "synthetic/index.html", "studies/tiny/index.html", "long-run/long-runs.html"}
    assert set(report.html.site) <= set(report.files)
    assert written == {p.relative_to(out).as_posix() for p in out.rglob("*.html")}
    site = check_site(out)
    assert site.problems == []
    assert site.images > 0 and site.cross_page_links > 0 and site.local_links > site.cross_page_links  # not vacuous
    # and the Markdown pages, where a dead link (item 6's long-run/long-run.md; the findings' link to a
    # study not run) is a dead link, where the HTML keeps its words only
    checked, dead = dead_markdown_links(out)
    assert dead == [] and checked > 20
    pngs = {p.relative_to(out).as_posix() for p in out.rglob("*.png")}
    shown = {(path.parent / src).resolve().relative_to(out.resolve()).as_posix()
             for path in report.html.site for src in re.findall(r'<img src="([^"]+)"', path.read_text())}
    assert pngs and shown == pngs, "every figure of the report is on a page, and only those"
    assert (out / "index.html").stat().st_size <= FRONT_PAGE_BYTES
    assert max(p.stat().st_size for p in report.html.site) <= PAGE_BYTES
    assert len(re.findall("<img", (out / "index.html").read_text())) <= 6  # a handful of figures at most
    from PIL import Image

    with Image.open(out / sorted(pngs)[0]) as image:  # a palette: about 3x smaller files
        assert image.mode == "P"


def test_the_long_runs_are_pages_of_the_report_and_the_findings_link_them(report) -> None:
    """Issue 47 item 6: findings.md linked long-run/long-run.md, which the report did not hold. With no
    long study in the results, the committed pages of make long are copied in, linked from the index
    and the findings, and on the site as the long runs' page."""
    from ilcforce.report import long_run

    out = report.out_dir
    committed = sorted(p.name for p in long_run.COMMITTED.iterdir() if p.is_file())
    assert "long-run.md" in committed
    for name in committed:
        assert (out / "long-run" / name).read_bytes() == (long_run.COMMITTED / name).read_bytes(), name
    assert "(long-run/long-run.md)" in (out / "findings.md").read_text()
    assert "(long-run/long-run.md)" in (out / "index.md").read_text()
    front = (out / "index.html").read_text()
    assert 'href="long-run/long-runs.html#p-long-run-long-run"' in front
    page = (out / "long-run" / "long-runs.html").read_text()
    assert 'src="long_run.png"' in page and 'id="p-long-run-long-run"' in page


def test_the_pages_in_a_real_browser(report, tmp_path: Path) -> None:
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (apt-get install chromium): the browser check is skipped")
    out = report.out_dir
    first_column = ("Array.from(document.querySelector('#p-synthetic-table2 table').tBodies[0].rows)"
                    ".map(function (r) { return r.cells[0].textContent; })")
    # wide tables fit: nothing wider than the window, every table inside the main column
    fits = ("(function () { var main = document.querySelector('main').getBoundingClientRect();"
            " var wide = Array.from(document.querySelectorAll('table')).filter(function (t) {"
            "  var r = t.getBoundingClientRect(); return r.right > main.right + 1 || t.scrollWidth > t.clientWidth + 1; });"
            " return [document.documentElement.scrollWidth <= window.innerWidth, wide.length,"
            " document.querySelectorAll('table').length]; })()")
    for page in report.html.site:
        expressions = {"fits": fits}
        if page.parent.name == "synthetic":
            expressions |= {
                "before": first_column,
                # click the first header twice: descending by method name
                "after": "(function () { var h = document.querySelector('#p-synthetic-table2 th');"
                         " h.click(); h.click(); return " + first_column + "; })()"}
        visit = open_page(chromium, page, expressions)
        assert visit.errors == [], page
        assert visit.broken_images == [], page
        fits_page, wide, tables_seen = visit.values["fits"]
        assert fits_page and wide == 0, (page, wide)
        assert tables_seen > 0 or page.name == "index.html" and page.parent == out, page
        if page.parent.name == "synthetic":
            assert visit.images > 0
            assert visit.values["before"] == ["c1", "c2", "c3"]
            assert visit.values["after"] == ["c3", "c2", "c1"]
        shot = tmp_path / f"{page.parent.name}.png"
        shot.write_bytes(visit.screenshot)
        assert visit.screenshot.startswith(b"\x89PNG") and shot.stat().st_size > 10_000  # a drawn page, not blank


def test_a_wide_table_wraps_to_the_page_instead_of_scrolling(pages: Path) -> None:
    """Issue 47 item 5: wide tables scrolled sideways at 1400 px. A table of 25 long columns, wider than
    the window when its cells do not wrap, fits the page's main column."""
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (apt-get install chromium): the browser check is skipped")
    html.write_html(pages)
    measure = ("(function () { var t = document.querySelector('#p-studies-mc-findings table');"
               " var main = document.querySelector('main').getBoundingClientRect();"
               " var fitted = [t.getBoundingClientRect().right <= main.right + 1, t.scrollWidth <= t.clientWidth + 1,"
               " document.documentElement.scrollWidth <= window.innerWidth];"
               " var cells = Array.from(t.querySelectorAll('th, td'));"
               " cells.forEach(function (c) { c.style.whiteSpace = 'nowrap'; });"
               " var natural = Math.max(t.getBoundingClientRect().width, t.scrollWidth);"
               " cells.forEach(function (c) { c.style.whiteSpace = ''; });"
               " return [fitted, natural > window.innerWidth]; })()")
    visit = open_page(chromium, pages / "studies" / "mc" / "index.html", {"measure": measure})
    fitted, would_overflow = visit.values["measure"]
    assert would_overflow, "the table is not wide: the check would pass vacuously"
    assert fitted == [True, True, True]


def test_the_site_check_finds_what_it_looks_for(tmp_path: Path) -> None:
    """The checker itself: a missing file, a fragment no element has, a remote image, a stylesheet, a
    path out of the report and a CSS url() are each found (otherwise the tests above could pass on a
    broken site)."""
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "there.html").write_text('<p id="here">x</p>')
    (tmp_path / "outside.png").write_bytes(b"x")
    report = tmp_path / "a"
    (report / "bad.html").write_text(
        '<a href="nope.html">1</a><a href="there.html#nowhere">2</a><a href="#missing">3</a>'
        '<img src="https://example.invalid/x.png"><img src="../outside.png"><link rel="stylesheet" href="there.html">'
        '<a href="https://example.invalid/ok">fine</a><a href="there.html#here">fine</a>'
        '<style>body { background: url(x.png); }</style>')
    problems = check_site(report).problems
    for needle in ("nope.html", "#nowhere", "#missing", "example.invalid/x.png", "../outside.png", "<link", "CSS"):
        assert sum(needle in p for p in problems) == 1, (needle, problems)
    assert len(problems) == 7, problems


def test_the_browser_check_finds_what_it_looks_for(tmp_path: Path) -> None:
    """The checker itself: a missing image, an undecodable one, console.error and an exception are
    each found (otherwise the test above could pass on a broken page)."""
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (apt-get install chromium): the browser check is skipped")
    page = tmp_path / "bad.html"
    page.write_text('<html><body><img src="nope.png"><img src="data:image/png;base64,AAAA">'
                    '<script>console.error("boom"); undefinedThing();</script></body></html>')
    visit = open_page(chromium, page)
    assert visit.images == 2 and len(visit.broken_images) == 2
    assert any("nope.png" in e for e in visit.errors)
    assert any("boom" in e for e in visit.errors)
    assert any("undefinedThing" in e for e in visit.errors)


def test_every_verdict_table_column_is_documented() -> None:
    """docs/tables.md has a row (name, unit, meaning) for every column of claims.csv and stability.csv."""
    from ilcforce.report import verdicts

    text = (Path(__file__).resolve().parents[1] / "docs" / "tables.md").read_text()
    claims_part, stability_part = text.split("## stability.csv")
    for columns, part in ((verdicts.CLAIM_COLUMNS, claims_part), (verdicts.STABILITY_COLUMNS, stability_part)):
        first_cells = re.findall(r"^\| ([^|]+) \|", part, re.M)
        names = {name for cell in first_cells for name in re.findall(r"`([^`]+)`", cell)}
        assert sorted(set(columns) - names) == [], "columns without a row in docs/tables.md"


def test_every_committed_long_run_page_is_on_the_long_runs_page(tmp_path: Path, monkeypatch) -> None:
    """Issue 47 item 6, the growth test's page too: every page make long committed (long-run.md and the
    held-out growth test's growth-heldout.md, with their figures and tables) is copied into a report
    whose results hold no long study, listed in its index and shown on the long runs' page; a file
    there that is no file of its own (a symlink) is not copied."""
    from ilcforce.report import long_run

    committed = tmp_path / "docs-long-run"
    committed.mkdir()
    (committed / "long-run.md").write_text("# Long runs: bounded?\n\n![growth](long_run.png)\n\n"
                                           "[held out](growth-heldout.md)\n", encoding="utf-8")
    (committed / "growth-heldout.md").write_text("# The growth test out of sample\n\n| a |\n|---|\n| 1 |\n",
                                                 encoding="utf-8")
    (committed / "growth_heldout.csv").write_text("a\n1\n", encoding="utf-8")
    (committed / "long_run.png").write_bytes((Path(__file__).parent / "browser.py").read_bytes()[:10])
    (tmp_path / "secret.md").write_text("# secret\n", encoding="utf-8")
    (committed / "linked.md").symlink_to(tmp_path / "secret.md")
    monkeypatch.setattr(long_run, "COMMITTED", committed)
    results = tmp_path / "results"
    for method in ("c1", "c2", "c3"):
        write_store(results / "paper" / f"{method}.h5", method)
    summary = write_report(results, tmp_path / "report", formats=())
    out = summary.out_dir
    assert sorted(p.name for p in (out / "long-run").iterdir()) == [
        "growth-heldout.md", "growth_heldout.csv", "long-run.md", "long-runs.html", "long_run.png"]
    index = (out / "index.md").read_text(encoding="utf-8")
    assert "[Long runs: bounded?](long-run/long-run.md)" in index
    assert "[The growth test out of sample](long-run/growth-heldout.md)" in index
    page = (out / "long-run" / "long-runs.html").read_text(encoding="utf-8")
    assert page.index('id="p-long-run-long-run"') < page.index('id="p-long-run-growth-heldout"')
    assert 'href="#p-long-run-growth-heldout"' in page and 'src="long_run.png"' in page
    assert check_site(out).problems == []
