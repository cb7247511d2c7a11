"""The one-page HTML report (ilcforce/report/html.py): built from the Markdown pages, in the order
summary, studies, experiments, tuning; links within the page; provenance folded; nothing loaded
from the network; and, in headless Chromium, no console error, no broken image, sortable tables."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from browser import find_chromium, open_page
from ilcforce.report import html
from ilcforce.report.build import write_report
from test_report import write_store

#: The issue's bound on what a reader downloads: the page with every figure it shows.
MAX_PAGE_BYTES = 25 * 1024 * 1024


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
        "studies/mc/findings.md": "# Study mc\n\nfindings\n",
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


def test_the_page_holds_every_linked_page_in_the_reader_s_order(pages: Path) -> None:
    page = html.write_html(pages)
    text = page.path.read_text()
    assert page.path == pages / "index.html"
    assert "never linked" not in text  # the Markdown's own links decide what is on the page
    order = [text.index(f'id="{anchor}"') for anchor in
             ("group-summary", "p-findings", "p-index", "summary-paper-table2", "group-studies",
              "p-studies-mc-report", "p-studies-mc-findings", "group-experiments", "p-paper-report",
              "p-paper-table2", "group-tuning", "p-tuning-t-report")]
    assert order == sorted(order), "summary, studies, experiments, tuning, each in the order linked"
    # links between pages are links within the page, to the page's section (a fragment is dropped)
    assert 'href="#p-paper-report"' in text and 'href="#p-studies-mc-findings"' in text
    assert 'href="#p-paper-table2"' in text
    assert not re.search(r'href="[^"#]*\.md', text), "a link to a Markdown file left on the page"
    # figures by relative path from the page, lazy; a missing one is said in words, never a broken image
    assert 'src="studies/mc/fig3.png"' in text and 'loading="lazy"' in text
    assert "[figure not written: paper/fig9.png]" in text and 'src="paper/fig9.png"' not in text
    assert page.figures == 1


def test_provenance_and_long_blocks_are_folded(pages: Path) -> None:
    text = html.write_html(pages).path.read_text()
    section = text[text.index('id="p-paper-report"'):text.index('id="p-paper-table2"')]
    folds = re.findall(r"<details><summary>(.*?)</summary>(.*?)</details>", section, re.S)
    assert [label for label, _ in folds] == ["Provenance", "toml block, 40 lines"]
    provenance = folds[0][1]
    assert "c3.h5" in provenance and "key39 = 39" in provenance and "Command lines" in provenance
    assert "Table 2" not in provenance  # the fold ends at the next heading of its level
    assert "<h2>Table 2</h2>" in section


def test_nothing_on_the_page_reaches_the_network(pages: Path) -> None:
    text = html.write_html(pages).path.read_text()
    assert not re.search(r'(src|href)="(https?:)?//', text)
    assert "<link" not in text and "<script src" not in text and "@import" not in text


def test_no_markdown_no_page(tmp_path: Path) -> None:
    assert html.write_html(tmp_path) is None
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory):
    """The report of a small synthetic experiment (every run figure drawn)."""
    root = tmp_path_factory.mktemp("results")
    for method in ("c1", "c2", "c3"):
        write_store(root / "synthetic" / f"{method}.h5", method)
    return write_report(root, tmp_path_factory.mktemp("report"), formats=("png",))


def test_write_report_writes_the_page_beside_the_markdown(report) -> None:
    assert report.html is not None and report.html.path == report.out_dir / "index.html"
    assert report.html.path in report.files
    pngs = {p.relative_to(report.out_dir).as_posix() for p in report.out_dir.rglob("*.png")}
    text = report.html.path.read_text()
    shown = set(re.findall(r'<img src="([^"]+)"', text))
    assert pngs and shown == pngs, "every figure of the report is on the page, and only those"
    assert report.html.total_bytes <= MAX_PAGE_BYTES
    from PIL import Image

    with Image.open(report.out_dir / sorted(pngs)[0]) as image:  # a palette: about 3x smaller files
        assert image.mode == "P"


def test_the_page_in_a_real_browser(report, tmp_path: Path) -> None:
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (apt-get install chromium): the browser check is skipped")
    first_column = ("Array.from(document.querySelector('#p-synthetic-table2 table').tBodies[0].rows)"
                    ".map(function (r) { return r.cells[0].textContent; })")
    visit = open_page(chromium, report.html.path, {
        "before": first_column,
        # click the first header twice: descending by method name
        "after": "(function () { var h = document.querySelector('#p-synthetic-table2 th');"
                 " h.click(); h.click(); return " + first_column + "; })()",
    })
    assert visit.errors == []
    assert visit.broken_images == []
    assert visit.images == report.html.figures > 0
    assert visit.values["before"] == ["c1", "c2", "c3"]
    assert visit.values["after"] == ["c3", "c2", "c1"]
    shot = tmp_path / "index.png"
    shot.write_bytes(visit.screenshot)
    assert visit.screenshot.startswith(b"\x89PNG") and shot.stat().st_size > 10_000  # a drawn page, not blank


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
