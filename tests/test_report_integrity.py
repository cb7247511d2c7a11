"""The report against a determined user (issue 46, items 1-4 and 12; issue 47, item 7), with real
files and real command-line processes: nothing outside the report folder is read into the page,
nothing remote is referenced by it, no experiment name collides with the report's own files or
breaks a store, no user's folder is replaced unasked, and a stopped report leaves the previous one
whole."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ilcforce.report import html, links
from site_check import check_site
from ilcforce.report.folder import is_report
from ilcforce.report.table_write import inert_markdown
from ilcforce.store.schema import REPORT_MARKER, RESERVED_NAMES

#: A run of a fraction of a second (0.2 s of the reference, one iteration).
TINY = "[reference]\nduration = 0.2\n"


def _cli(*args: str, cwd: Path | None = None, env: dict | None = None, timeout: float = 300,
         ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ilcforce", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env={**os.environ, **(env or {})})


def _one_line_exit_2(done: subprocess.CompletedProcess, *words: str) -> None:
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, (done.returncode, done.stdout, done.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in done.stderr, done.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# -- items 1 and 2: the description's links and images ---------------------------------------------


#: Each way a description can name a file outside the report, with the word its file holds: were
#: any of them followed, its word would be on the page.
def _hostile_forms(root: Path, home: Path) -> dict[str, str]:
    outside = root / "outside"
    return {
        "LEAK_ABSOLUTE": f"[words-absolute]({outside}/absolute.md)",
        "LEAK_HOME": "[words-home](~/home.md)",
        "LEAK_FILE_URL": f"[words-file_url](file://{outside}/file_url.md)",
        "LEAK_AUTOLINK": f"<file://{outside}/autolink.md>",
        "LEAK_UP": "[words-up](../../outside/up.md)",
        "LEAK_ENCODED_UP": "[words-encoded_up](%2e%2e/%2e%2e/outside/encoded_up.md)",
        "LEAK_ENCODED_SLASH": "[words-encoded_slash](..%2f..%2foutside%2fencoded_slash.md)",
        "LEAK_BACKSLASH": "[words-backslash](..\\..\\outside\\backslash.md)",
        "LEAK_ENCODED_ABSOLUTE": f"[words-encoded_absolute](%2F{str(outside).lstrip('/')}/encoded_absolute.md)",
        "LEAK_NETWORK_PATH": f"[words-network_path](//localhost{outside}/network_path.md)",
        "LEAK_REFERENCE": "[words-reference][ref]",
        "LEAK_QUERY": f"[words-query]({outside}/query.md?x=1#top)",
        "LEAK_ANGLE": f"[words-angle](<{outside}/angle.md>)",
    }


@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A run whose description names files outside the report in every form above, a remote image
    and a local image outside; its report built by the command line."""
    root = tmp_path_factory.mktemp("hostile")
    home = root / "home"
    home.mkdir()
    outside = root / "outside"
    outside.mkdir()
    forms = _hostile_forms(root, home)
    files = {"LEAK_ABSOLUTE": outside / "absolute.md", "LEAK_HOME": home / "home.md",
             "LEAK_FILE_URL": outside / "file_url.md", "LEAK_AUTOLINK": outside / "autolink.md",
             "LEAK_UP": outside / "up.md", "LEAK_ENCODED_UP": outside / "encoded_up.md",
             "LEAK_ENCODED_SLASH": outside / "encoded_slash.md", "LEAK_BACKSLASH": outside / "backslash.md",
             "LEAK_ENCODED_ABSOLUTE": outside / "encoded_absolute.md",
             "LEAK_NETWORK_PATH": outside / "network_path.md", "LEAK_REFERENCE": outside / "reference.md",
             "LEAK_QUERY": outside / "query.md", "LEAK_ANGLE": outside / "angle.md"}
    for word, path in files.items():
        path.write_text(f"# {word}\n\n{word} was read into the report\n", encoding="utf-8")
    Image = pytest.importorskip("PIL.Image")
    Image.new("RGB", (4, 4)).save(outside / "outside.png")
    description = (" ".join(forms.values()) + f" ![remote](https://example.invalid/t.png)"
                   ' <img src="https://example.invalid/raw.png">'
                   f" ![local outside]({outside}/outside.png) ![net](//example.invalid/n.png)"
                   f"\n\n[ref]: {outside}/reference.md")
    experiment = root / "hostile.toml"
    toml_text = '[experiment]\nname = "hostile"\ndescription = """' + description.replace("\\", "\\\\") + '"""\n' + TINY
    experiment.write_text(toml_text, encoding="utf-8")
    results = root / "results"
    made = _cli("simulate", "-m", "c1", "-n", "1", "-c", str(experiment), "--results", str(results))
    assert made.returncode == 0, made.stderr
    out = root / "report"
    done = _cli("report", "--results", str(results), "--out", str(out), "-j", "1", "-q", env={"HOME": str(home)})
    return {"done": done, "out": out, "words": list(files), "outside": outside, "forms": forms}


def test_no_link_of_a_description_brings_a_file_from_outside_into_the_report(hostile):
    """Issue 46 item 1: ``[notes](/some/where/secret.md)`` in a description was followed when the page
    was built (only ``../`` was stopped), and the file embedded with its own navigation entry."""
    done, out = hostile["done"], hostile["out"]
    assert done.returncode == 0, done.stderr
    pages = {path: path.read_text(encoding="utf-8") for path in sorted(out.rglob("*.html"))}
    assert out / "hostile" / "index.html" in pages and out / "index.html" in pages
    page = "\n".join(pages.values())  # every page of the site
    report_md = (out / "hostile" / "report.md").read_text(encoding="utf-8")
    for form in hostile["forms"].values():  # the description, every form in it, reached the Markdown
        assert inert_markdown(form) in report_md, form
    everything = b"".join(_files(out).values()).decode("utf-8", "replace")
    leaked = [word for word in hostile["words"] if f"{word} was read" in everything]
    assert leaked == [], f"read into the report: {leaked}"
    # no link on any page names a file outside the report, and every link and image resolves inside it
    assert check_site(out).problems == []
    hrefs = [(path, h) for path, text in pages.items() for h in re.findall(r'href="([^"]*)"', text)]
    assert hrefs, "no link found: the check would pass vacuously"
    # a page links another by a relative path (``../index.html``): every one lands inside the report
    assert not [h for path, h in hrefs if h.startswith(("/", "~", "file:", "\\")) or "%2e" in h.lower()
                or str(hostile["outside"]) in h
                or not (path.parent / h.partition("#")[0]).resolve().is_relative_to(out.resolve())], hrefs
    # each link's words are kept, as text (not a link)
    hostile_page = pages[out / "hostile" / "index.html"]
    section = hostile_page[hostile_page.index('id="p-hostile-report"'):]
    words = re.findall(r"\[(words-[a-z_]+)\]", " ".join(hostile["forms"].values()))
    assert len(words) == 12
    for word in words:
        assert word in section and not re.search(f"<a [^>]*>{word}</a>", section), word
    for text in pages.values():
        assert "<h1>LEAK" not in text and "LEAK_" not in re.sub(r"<section.*?</section>", "", text, flags=re.S), \
            "a file from outside has its own entry in the navigation"


def test_a_remote_or_outside_image_is_never_referenced_and_the_report_succeeds(hostile):
    """Issue 46 item 2: ``![t](https://host/t.png)`` became a remote ``<img>`` on the offline page, and
    the report then exited 2 after index.html was written. Neither the page nor any Markdown page of
    the report (read by a viewer that shows images and raw HTML) references an image or a resource
    outside the report."""
    from markdown_it import MarkdownIt

    done, out = hostile["done"], hostile["out"]
    assert done.returncode == 0 and "written to" in done.stdout, done.stderr
    pages = {path: path.read_text(encoding="utf-8") for path in sorted(out.rglob("*.html"))}
    page = "\n".join(pages.values())  # every page of the site
    sources = [path.parent / src for path, text in pages.items() for src in re.findall(r'<img src="([^"]*)"', text)]
    assert sources, "no figure on any page: the check would pass vacuously"
    assert all(s.is_file() and s.resolve().is_relative_to(out.resolve()) for s in sources), sources
    assert "example.invalid" not in " ".join(re.findall(r'(?:src|href)="([^"]*)"', page))
    assert not [s for s in re.findall(r'(?:src|href)="([^"]*)"', page) if "outside" in s]
    viewer = MarkdownIt("commonmark", {"html": True})  # as a Markdown viewer reads the pages

    def tokens(items):
        for token in items:
            yield token
            yield from tokens(token.children or [])

    pages = sorted(out.rglob("*.md"))
    description_seen = 0
    for path in pages:
        text = path.read_text(encoding="utf-8")
        description_seen += "example.invalid/t.png" in text
        for token in tokens(viewer.parse(text)):
            if token.type == "image":
                src = str(token.attrGet("src"))
                assert "://" not in src and not src.startswith(("/", "~")), (path, src)
                assert (path.parent / src).resolve().is_relative_to(out.resolve()), (path, src)
            assert not (token.type.startswith("html") and "<img" in token.content.lower()), (path, token.content)
    assert description_seen >= 2, "the description is on the pages (report, index): the check would be vacuous"


def test_the_page_says_an_image_from_outside_in_words(tmp_path: Path):
    """The page's own check (behind the pages' escaping): an image naming a URL or a file outside the
    report is words, never an ``<img>``, and the page is written."""
    Image = pytest.importorskip("PIL.Image")
    Image.new("RGB", (4, 4)).save(tmp_path / "outside.png")
    out = tmp_path / "report"
    out.mkdir()
    (out / "index.md").write_text(f"# ilcforce reports\n\n![remote](https://example.invalid/t.png) "
                                  f"![net](//example.invalid/n.png) ![abs]({tmp_path}/outside.png) "
                                  f"![up](../outside.png)\n", encoding="utf-8")
    page = html.write_html(out)
    text = page.path.read_text(encoding="utf-8")
    assert "<img" not in text and page.figures == 0
    for alt in ("remote", "net", "abs", "up"):
        assert f"[image not shown: not a file of this report: {alt}]" in text, alt


@pytest.mark.parametrize("href", [
    "/etc/passwd.md", "~/x.md", "file:///etc/x.md", "FILE:/x.md", "%2e%2e/%2e%2e/x.md", "..%2f..%2fx.md", "..%5cx.md",
    "..\\x.md", "//host/x.md", "C:/x.md", "https://host/x.md", "data:image/png;base64,AAAA", "%00.md",
    "a/../../../x.md", "%2fetc/x.md", "%ff.md", "link/x.md", "loop/x.md",
])
def test_local_target_keeps_only_files_inside_the_report(tmp_path: Path, href: str):
    """The one resolver (attack variants beyond the issue's): every form that leaves the folder,
    a symlink out and a symlink loop included, names nothing."""
    out = tmp_path / "report"
    (out / "exp").mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    (out / "exp" / "link").symlink_to(tmp_path / "elsewhere")
    (out / "exp" / "loop").symlink_to(out / "exp" / "loop")
    assert links.local_target(out, "exp", href) is None


def test_local_target_keeps_what_is_inside(tmp_path: Path):
    out = tmp_path / "report"
    (out / "exp" / "inner").mkdir(parents=True)
    (out / "exp" / "alias").symlink_to(out / "exp" / "inner")
    assert links.local_target(out, "exp", "fig%201.png") == "exp/fig 1.png"
    assert links.local_target(out, "exp", "../studies/s/report.md#x") == "studies/s/report.md"
    assert links.local_target(out, "exp", "alias/x.md") == "exp/alias/x.md"
    # decoded once, as a browser does: a doubly encoded '..' is a folder of that literal name, inside
    assert links.local_target(out, "exp", "%252e%252e/%252e%252e/x.md") == "exp/%2e%2e/%2e%2e/x.md"


# -- items 3 and 12: one name rule, where the name is read -----------------------------------------


@pytest.mark.parametrize("name", ["index.md", "index.html", "findings.md", "Claims.CSV", "studies", "tuning",
                                  "report", REPORT_MARKER, "e\\nx", "a b", "../x", ".hidden", "x\\\\y", "é" * 2])
def test_an_experiment_name_the_report_or_a_store_cannot_take_is_refused_by_every_command(tmp_path: Path, name):
    """Issue 46 items 3 and 12: ``index.md`` was accepted by ``simulate`` and then broke ``report``;
    ``"e\\nx"`` passed ``config`` and ``simulate`` wrote a store ``validate`` refused."""
    experiment = tmp_path / "bad.toml"
    experiment.write_text(f'[experiment]\nname = "{name}"\n{TINY}', encoding="utf-8")
    study = tmp_path / "s.toml"
    study.write_text('[study]\nname = "s"\nexperiment = "bad.toml"\nmethods = ["c1"]\nseeds = [0]\n'
                     '[study.set]\n"experiment.iterations" = 1\n', encoding="utf-8")
    results = tmp_path / "results"
    commands = [["config", "-c", str(experiment)]]
    if name in ("index.md", "findings.md", "e\\nx"):  # the issue's own: every command that reads a name
        commands += [["simulate", "-m", "c1", "-n", "1", "-c", str(experiment), "--results", str(results)],
                     ["compare", "-n", "1", "-c", str(experiment), "--results", str(results)],
                     ["study", str(study), "--results", str(results)]]
    for command in commands:
        _one_line_exit_2(_cli(*command, cwd=tmp_path), "experiment.name")
    assert not results.exists(), "a refused name wrote something"
    # --set takes the same rule
    _one_line_exit_2(_cli("config", "--set", f"experiment.name={name}"), "experiment.name")


def test_a_results_folder_named_as_a_report_file_is_skipped_with_a_warning(tmp_path: Path):
    """A folder renamed by hand (the configuration can no longer make one) never lands on the
    report's own index.md."""
    results = tmp_path / "results"
    experiment = tmp_path / "ok.toml"
    experiment.write_text(f'[experiment]\nname = "ok"\n{TINY}', encoding="utf-8")
    assert _cli("simulate", "-m", "c1", "-n", "1", "-c", str(experiment), "--results", str(results)).returncode == 0
    (results / "ok").rename(results / "index.md")
    (results / "fine").mkdir()
    done = _cli("report", "--results", str(results), "--out", str(tmp_path / "rep"), "-j", "1", "-q")
    assert done.returncode == 2 and "index.md: skipped" in done.stderr, done.stderr
    assert not (tmp_path / "rep").exists()
    assert {"index.md", "index.html", "findings.md", "claims.csv", "stability.csv"} <= RESERVED_NAMES


# -- item 4 and issue 47 item 7: the report's folder -----------------------------------------------


@pytest.fixture(scope="module")
def small_results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four experiments of one tiny run each (a report of a few seconds, with figures)."""
    root = tmp_path_factory.mktemp("small")
    results = root / "results"
    for name in ("e1", "e2", "e3", "e4"):
        experiment = root / f"{name}.toml"
        experiment.write_text(f'[experiment]\nname = "{name}"\n{TINY}', encoding="utf-8")
        made = _cli("simulate", "-m", "c1", "-n", "1", "-c", str(experiment), "--results", str(results))
        assert made.returncode == 0, made.stderr
    return results


@pytest.fixture(scope="module")
def one_result(small_results: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A results folder of one experiment, ``e5`` (a copy of e4's run under a name small_results
    does not hold): its report takes a third of small_results' time. Where a test only needs *a*
    report to be written (the folder rules, the clean-up after a stop), this one serves: those rules
    do not depend on how many experiments a report holds."""
    import shutil

    results = tmp_path_factory.mktemp("one") / "results"
    shutil.copytree(small_results / "e4", results / "e5")
    return results


@pytest.fixture(scope="module")
def small_report(small_results: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """small_results' report, built once by the command line; tests copy it (shutil.copytree keeps
    every byte) rather than build it again."""
    out = tmp_path_factory.mktemp("small-report") / "report"
    done = _cli("report", "--results", str(small_results), "--out", str(out), "-j", "1", "-q")
    assert done.returncode == 0, done.stderr
    assert "index.html" in _files(out) and is_report(out)
    return out


def test_report_never_replaces_a_folder_that_is_not_a_report(one_result: Path, tmp_path: Path):
    """Issue 46 item 4: ``report --out`` into a user's folder replaced its index.md, findings.md,
    index.html and claims.csv without asking (``export`` refuses the same)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("index.md", "findings.md", "index.html", "claims.csv"):
        (mine / name).write_text(f"my own {name}\n", encoding="utf-8")
    before = _files(mine)
    _one_line_exit_2(_cli("report", "--results", str(one_result), "--out", str(mine), "-q"), str(mine),
                     "not an ilcforce report")
    assert _files(mine) == before and sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
    # a folder holding the results is refused too (the report replaces its folder whole)
    _one_line_exit_2(_cli("report", "--results", str(one_result), "--out", str(one_result.parent), "-q"),
                     "holds the results")
    # an empty folder, an absent one and a report of its own are written
    empty = tmp_path / "empty"
    empty.mkdir()
    for target in (empty, tmp_path / "new", tmp_path / "new"):
        done = _cli("report", "--results", str(one_result), "--out", str(target), "-j", "1", "-q")
        assert done.returncode == 0, done.stderr
        assert (target / "index.html").is_file() and (target / REPORT_MARKER).is_file() and is_report(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "mine", "new"], "no building folder left"


def _staging(out: Path) -> list[Path]:
    return [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.partial-")]


def _stop_midway(small_results: Path, out: Path, how: int) -> subprocess.CompletedProcess:
    """Start a report into ``out`` and send ``how`` once it has written files into its building
    folder (but not yet moved it into place)."""
    process = subprocess.Popen([sys.executable, "-m", "ilcforce", "report", "--results", str(small_results),
                                "--out", str(out), "-j", "1", "-q"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if any(any(p.suffix == ".png" for p in s.rglob("*")) for s in _staging(out)):
            break
        time.sleep(0.01)
    assert process.poll() is None, "the report finished before it could be stopped"
    process.send_signal(how)
    stdout, stderr = process.communicate(timeout=60)
    return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)


@pytest.mark.parametrize("how", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["int", "term", "kill"])
def test_a_stopped_report_leaves_the_previous_one_whole_and_a_new_folder_absent(small_results, small_report,
                                                                                 one_result, tmp_path, how):
    """Issue 47 item 7: a stopped report left 53 files and no index.html in a new folder, or new
    figures beside an old index.html in an existing one.

    The report stopped is small_results' (four experiments: long enough to be stopped midway); the
    previous report is a copy of the one the fixture built; the reports after the stop, which must
    clear what it left and replace the old folder whole, are one_result's (one experiment, e5)."""
    import shutil

    fresh = tmp_path / "fresh"
    code = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGKILL: -signal.SIGKILL}[how]
    stopped = _stop_midway(small_results, fresh, how)
    assert stopped.returncode == code, stopped.stderr
    assert not fresh.exists(), "a stopped report left a half folder"
    if how != signal.SIGKILL:
        assert _staging(fresh) == [] and "Traceback" not in stopped.stderr, stopped.stderr
    old = tmp_path / "old"
    shutil.copytree(small_report, old)
    before = _files(old)
    assert "index.html" in before and "e4/report.md" in before
    stopped = _stop_midway(small_results, old, how)
    assert stopped.returncode == code, stopped.stderr
    assert _files(old) == before, "a stopped report changed the previous one"
    # whatever a killed report left beside is removed by the next report, which replaces the old one
    # (built in this process: the command's own exit codes are tested above and by
    # test_report_never_replaces_a_folder_that_is_not_a_report; the clean-up is write_report's)
    from ilcforce.report.build import write_report

    write_report(one_result, old, jobs=1)
    assert (old / "e5" / "report.md").is_file() and not (old / "e4").exists(), "replaced whole, not merged"
    write_report(one_result, fresh, jobs=1)
    assert _staging(old) == [] and _staging(fresh) == [] and is_report(fresh)


def test_a_link_to_a_file_the_report_does_not_hold_keeps_its_words_only(tmp_path: Path):
    """A dead link inside the report (a description naming ``notes.md`` the report never wrote) is
    words on the page, where a file the report holds stays a link."""
    (tmp_path / "index.md").write_text("# ilcforce reports\n\n[gone](notes.md) [table](claims.csv) [folder](exp/)\n",
                                       encoding="utf-8")
    (tmp_path / "claims.csv").write_text("a\n1\n", encoding="utf-8")
    (tmp_path / "exp").mkdir()
    text = html.write_html(tmp_path).path.read_text(encoding="utf-8")
    assert '<a href="claims.csv">table</a>' in text
    assert "gone" in text and 'href="notes.md"' not in text
    assert "folder" in text and 'href="exp' not in text  # a folder is no file of the site
    assert check_site(tmp_path).problems == []


@pytest.mark.parametrize("text", [
    "![t](https://example.invalid/t.png)", "\\![t](https://example.invalid/t.png)",
    "\\\\![t](https://example.invalid/t.png)", '<img src="https://example.invalid/raw.png">',
    "\\<img src=x>", "\\\\<img src=x>", "<https://example.invalid/auto>", "![a][r]\n\n[r]: https://example.invalid/r.png",
    "![![nested](https://example.invalid/n.png)](x)", "plain words, a < b > c",
])
def test_a_users_text_shows_as_written_and_embeds_nothing(text: str):
    """inert_markdown, attacked with backslashes that would undo its escapes: a viewer that shows
    images and raw HTML embeds nothing, and shows the text as written."""
    from markdown_it import MarkdownIt

    viewer = MarkdownIt("commonmark", {"html": True})
    tokens = [t for block in viewer.parse(inert_markdown(text)) for t in [block, *(block.children or [])]]
    assert not [t for t in tokens if t.type == "image" or t.type.startswith("html")], inert_markdown(text)
    shown = viewer.renderInline(inert_markdown(text.split("\n\n")[0]))
    assert shown == text.split("\n\n")[0].replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;") \
        .replace('"', "&quot;"), shown


def test_a_folder_made_at_the_target_while_the_report_is_built_is_left_alone(tmp_path: Path):
    """Attack: the folder is checked before the report is built (which takes minutes) and again
    before the new report takes its place: a user's folder made there meanwhile is never replaced."""
    from ilcforce.report import folder

    target = tmp_path / "out"
    with folder.building(target) as staging:
        (staging / "index.md").write_text("# ilcforce reports\n", encoding="utf-8")
        target.mkdir()
        (target / "mine.txt").write_text("mine\n", encoding="utf-8")
        with pytest.raises(folder.ReportFolderError, match="not an ilcforce report"):
            folder.publish(staging, target, "test")
    assert [p.name for p in target.iterdir()] == ["mine.txt"] and (target / "mine.txt").read_text() == "mine\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"], "the building folder is removed"
