"""A study's journal records under attack: changed digits, wrong types and sizes, cells the study
does not have, another study's journal. Each record is checked against its study before anyone
uses it: refused records are named by `validate`, skipped by readers, moved aside by the next
`study` run (which computes their cells again), and never crash a command.

The journal is left unconsolidated by stopping the driver's consolidation (as a kill -9 after the
cells' commits would), with real files and the real CLI.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.store.study import StudyStore
from ilcforce.study import run_study, tidy_metrics

from test_study import small_study


def _journal_only(tmp_path: Path, monkeypatch, name: str = "tiny", **study) -> Path:
    """Run a study whose cells stay in the journal (never consolidated); the store's path."""
    with monkeypatch.context() as patch:
        patch.setattr(StudyStore, "consolidate", lambda self, now=0.0: None)
        summary = run_study(small_study(name=name, **study), tmp_path, workers=1)
    records = sorted((tmp_path / "studies" / f"{name}.h5.journal").glob("*.json"))
    assert len(records) == summary.total, "every cell is in the journal"
    return summary.path


def _invoke(*args: str):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output and not isinstance(result.exception, (KeyError, IndexError, TypeError,
                                                                                  ValueError)), result.output
    return result


def _rewrite(record: Path, change) -> None:
    data = json.loads(record.read_text(encoding="utf-8"))
    change(data)
    record.write_text(json.dumps(data), encoding="utf-8")


@pytest.fixture()
def clean(tmp_path_factory):
    """The clean study's tidy table (seeds 0-1, methods c1 and c3, one setting)."""
    root = tmp_path_factory.mktemp("clean")
    return tidy_metrics(run_study(small_study(), root, workers=1).path)


def test_a_changed_digit_is_refused_named_and_its_cell_computed_again(tmp_path, monkeypatch, clean):
    """A metric changed in a record after a kill -9 (found by an attack: 0.00354 -> 0.10354 passed
    `validate` and was folded in): the checksum catches it; `validate` names it, `export` leaves the
    cell out, the next `study` run moves it aside with one line and computes the cell again."""
    path = _journal_only(tmp_path, monkeypatch)
    record = path.parent / "tiny.h5.journal" / "0-1-c3.json"
    text = record.read_text(encoding="utf-8")
    value = json.loads(text)["rows"][1]["position_error_rms"]
    changed = repr(value + 0.1)
    assert text.count(repr(value)) == 1
    record.write_text(text.replace(repr(value), changed), encoding="utf-8")
    checked = _invoke("validate", path)
    assert checked.exit_code == 0, checked.output
    assert ("0-1-c3.json: refused (its checksum does not match its content (changed after it was written))"
            in checked.output), checked.output
    exported = _invoke("export", path, "--out", tmp_path / "t.csv")
    assert exported.exit_code == 0, exported.output
    table = pd.read_csv(tmp_path / "t.csv")
    assert len(table) == len(clean) - 3 and not ((table["seed"] == 1) & (table["method"] == "c3")).any()
    rerun = _invoke("study", _study_file(tmp_path), "--results", tmp_path, "--workers", "1", "--quiet")
    assert rerun.exit_code == 0, rerun.output
    warnings = [line for line in rerun.output.splitlines() if "quarantine" in line]
    assert len(warnings) == 1 and "0-1-c3.json" in warnings[0] and "runs again" in warnings[0], rerun.output
    assert (path.parent / "tiny.h5.journal" / ".quarantine" / "0-1-c3.json").read_text(encoding="utf-8").count(
        changed) == 1, "the refused record is kept aside, not deleted"
    pd.testing.assert_frame_equal(tidy_metrics(path), clean, check_exact=True)
    again = _invoke("validate", path)
    assert "1 refused record(s) moved aside earlier" in again.output, again.output


def _study_file(tmp_path: Path) -> Path:
    study = tmp_path / "tiny.toml"
    study.write_text('[study]\nname = "tiny"\nmethods = ["c1", "c3"]\nseeds = "0-1"\n[study.set]\n'
                     '"experiment.iterations" = 3\n"reference.duration" = 0.2\n', encoding="utf-8")
    return study


def _reseal(record: Path, change) -> None:
    """Change a record and give it a valid checksum again: only the checks against the study can
    refuse it."""
    from ilcforce.store.records import checksum as _checksum

    def both(data):
        change(data)
        data["checksum"] = _checksum(data)

    _rewrite(record, both)


#: (file the record is written to, change to the record of 0-0-c1 before it is resealed, the reason)
RESEALED = [
    ("0-0-c1.json", lambda r: r.update(seed="abc"), "setting and seed must be integers"),
    ("0-0-c1.json", lambda r: r.update(seed=None), "setting and seed must be integers"),
    ("0-0-c1.json", lambda r: r.update(seed=10**30), "setting and seed must be integers"),
    ("0-0-c1.json", lambda r: r["rows"].append(dict(r["rows"][0])), "4 metric rows; a cell of this setting has 1 .. 3"),
    ("0-0-c1.json", lambda r: r["rows"][2].update(iteration=5), "row 2 is iteration 5, expected 2"),
    ("0-0-c1.json", lambda r: r["rows"][0].pop("status"), "row 0 lacks ['status']"),
    ("0-0-c1.json", lambda r: r["rows"][1].update(force_error_rms=[1, 2]), "row 1: force_error_rms"),
    ("0-0-c1.json", lambda r: r.update(rows=[]), "0 metric rows"),
    ("0-0-c1.json", lambda r: r.update(attempts=-1), "attempts -1"),
    ("0-0-c1.json", lambda r: r.update(state="complede"), "state 'complede'"),
    ("0-0-c1.json", lambda r: r.update(message={"a": 1}), "message is dict"),
    ("5-0-c1.json", lambda r: r.update(setting=5), "setting 5 is not one of the study's 1 settings"),
    ("0-7-c1.json", lambda r: r.update(seed=7), "seed 7, method 'c1' is not a cell any run of this study planned"),
    ("0-0-c2.json", lambda r: r.update(method="c2"), "seed 0, method 'c2' is not a cell"),
    ("0-0-c1.json", lambda r: r.update(setting_digest="0" * 64), "computed with other values of setting 0"),
    ("0-0-c1.json", lambda r: r.update(study="f" * 32), "it belongs to another study"),
    ("copy-of-0-0-c1.json", lambda r: None, "its name is not <setting>-<seed>-<method>.json"),
    ("0-1-c1.json", lambda r: None, "it holds cell 0-0-c1.json, not the cell of its file name"),
    ("0-0-c1.json", lambda r: r.pop("format"), "no checksum (written by an older ilcforce"),
]


@pytest.mark.parametrize("name, change, reason", RESEALED, ids=[r[2][:40] for r in RESEALED])
def test_a_record_that_does_not_fit_its_study_is_refused_everywhere(tmp_path, monkeypatch, name, change, reason):
    """Wrong types, sizes, ranges, a cell outside the study, a duplicate key under another file name,
    another study's record: refused with the reason named, even with a valid checksum, and never
    read (found by an attack: tracebacks in validate, export and study, 81 of 80 cells, an
    IndexError in report)."""
    path = _journal_only(tmp_path, monkeypatch, seeds="0-0", methods=("c1",))
    journal = path.parent / "tiny.h5.journal"
    original = journal / "0-0-c1.json"
    target = journal / name
    if target != original:
        shutil.copy(original, target)
    _reseal(target, change)
    good = target != original
    checked = _invoke("validate", path)
    assert checked.exit_code == 0, checked.output
    assert f"{name}: refused (" in checked.output and reason in checked.output, checked.output
    exported = _invoke("export", path, "--out", tmp_path / "t.csv")
    assert exported.exit_code == 0, exported.output
    assert exported.output.startswith(f"{3 if good else 0} rows written"), exported.output
    rerun = _invoke("study", _one_cell_file(tmp_path), "--results", tmp_path, "--workers", "1", "--quiet")
    assert rerun.exit_code == 0, rerun.output
    assert rerun.output.count("quarantine") == 1 and name in rerun.output, rerun.output
    assert (journal / ".quarantine" / name).exists()
    assert len(tidy_metrics(path)) == 3, "one cell of three iterations, never two"
    assert _invoke("validate", path).exit_code == 0


def _one_cell_file(tmp_path: Path) -> Path:
    study = tmp_path / "one.toml"
    study.write_text('[study]\nname = "tiny"\nmethods = ["c1"]\nseeds = "0-0"\n[study.set]\n'
                     '"experiment.iterations" = 3\n"reference.duration" = 0.2\n', encoding="utf-8")
    return study


@pytest.mark.parametrize("damage", ["nested", "huge", "binary", "list"])
def test_a_record_that_is_not_one_is_refused_in_bounded_time(tmp_path, monkeypatch, damage):
    """Deeply nested JSON (a RecursionError), a record larger than any cell's, bytes that are not
    UTF-8, a JSON list: named, never read as a cell."""
    path = _journal_only(tmp_path, monkeypatch, seeds="0-0", methods=("c1",))
    record = path.parent / "tiny.h5.journal" / "0-0-c1.json"
    record.write_bytes({"nested": b"[" * 100_000 + b"]" * 100_000, "huge": b" " * (17 << 20),
                        "binary": b"\xff\xfe{}", "list": b"[1, 2]"}[damage])
    why = {"nested": "JSON nested too deeply", "huge": "17825792 bytes, more than a record holds", "binary": "not UTF-8",
           "list": "a JSON list, not a record"}[damage]
    checked = _invoke("validate", path)
    assert checked.exit_code == 0 and f"0-0-c1.json: refused ({why}" in checked.output, checked.output
    assert _invoke("export", path, "--out", tmp_path / "t.csv").exit_code == 0


def test_a_record_naming_a_key_twice_is_refused(tmp_path, monkeypatch):
    """Issue 46 item 8: a second "rows" key before the real one leaves the record Python parses (the last
    wins) and its seal unchanged; a reader keeping the first would read no rows. Refused, named, never read."""
    path = _journal_only(tmp_path, monkeypatch, seeds="0-0", methods=("c1",))
    record = path.parent / "tiny.h5.journal" / "0-0-c1.json"
    data = record.read_bytes()
    record.write_bytes(data.replace(b"{", b'{"rows": [], ', 1))
    assert json.loads(record.read_bytes()) == json.loads(data)
    checked = _invoke("validate", path)
    assert checked.exit_code == 0 and "0-0-c1.json: refused (the key 'rows' appears twice" in checked.output, \
        checked.output
    assert _invoke("export", path, "--out", tmp_path / "t.csv").exit_code == 0
    assert len(pd.read_csv(tmp_path / "t.csv")) == 0


def test_a_symlinked_journal_of_another_study_is_refused(tmp_path, monkeypatch):
    """Study B's journal folder a symlink to study A's: B took A's cells as its own and A lost them
    (found by an attack). B's readers and driver now refuse the folder in one line, A keeps every cell."""
    first = _journal_only(tmp_path, monkeypatch, name="tiny")
    a_journal = first.parent / "tiny.h5.journal"
    before = sorted(p.name for p in a_journal.iterdir())
    second = run_study(small_study(name="other", seeds="0-0", methods=("c1",)), tmp_path, workers=1).path
    b_journal = second.parent / "other.h5.journal"
    shutil.rmtree(b_journal, ignore_errors=True)
    b_journal.symlink_to(a_journal.name)
    for args in (["validate", second], ["export", second, "--out", tmp_path / "b.csv"]):
        result = _invoke(*args)
        assert result.exit_code == 2 and "journal folder is a symbolic link" in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1
    study = tmp_path / "other.toml"
    study.write_text('[study]\nname = "other"\nmethods = ["c1"]\nseeds = "0-1"\n[study.set]\n'
                     '"experiment.iterations" = 3\n"reference.duration" = 0.2\n', encoding="utf-8")
    rerun = _invoke("study", study, "--results", tmp_path, "--workers", "1", "--quiet")
    assert rerun.exit_code == 2 and "journal folder is a symbolic link" in rerun.output, rerun.output
    assert sorted(p.name for p in a_journal.iterdir()) == before, "A's journal is untouched"
    assert _invoke("validate", first).output.count("refused") == 0


def test_a_bind_mounted_journal_of_another_study_is_refused(tmp_path, monkeypatch):
    """Study B's journal folder a bind mount of study A's (the symlink form is refused above): each
    driver quarantined the other's valid records. Both refuse it in one line; A keeps every cell."""
    first = _journal_only(tmp_path, monkeypatch, name="tiny")
    a_journal = first.parent / "tiny.h5.journal"
    before = sorted(p.name for p in a_journal.iterdir())
    second = run_study(small_study(name="other", seeds="0-0", methods=("c1",)), tmp_path, workers=1).path
    b_journal = second.parent / "other.h5.journal"
    b_journal.mkdir(exist_ok=True)
    if subprocess.run(["mount", "--bind", str(a_journal), str(b_journal)], capture_output=True).returncode != 0:
        pytest.skip("bind mounts need CAP_SYS_ADMIN here")
    try:
        for args in (["validate", second], ["export", second, "--out", tmp_path / "b.csv"]):
            result = _invoke(*args)
            assert result.exit_code == 2 and "journal folder is a mount point" in result.output, result.output
        study = tmp_path / "other.toml"
        study.write_text('[study]\nname = "other"\nmethods = ["c1"]\nseeds = "0-1"\n[study.set]\n'
                         '"experiment.iterations" = 3\n"reference.duration" = 0.2\n', encoding="utf-8")
        rerun = _invoke("study", study, "--results", tmp_path, "--workers", "1", "--quiet")
        assert rerun.exit_code == 2 and "journal folder is a mount point" in rerun.output, rerun.output
        assert sorted(p.name for p in a_journal.iterdir()) == before, "A's journal is untouched"
    finally:
        subprocess.run(["umount", str(b_journal)], check=True)


def test_a_copied_journal_of_another_study_is_refused_record_by_record(tmp_path, monkeypatch):
    """The same study name and settings in another results folder: a copy of its journal folder
    holds records of another store (another study id); the driver moves them aside and computes
    its own cells; the source keeps its records."""
    source = _journal_only(tmp_path / "a", monkeypatch)
    target = run_study(small_study(seeds="0-0", methods=("c1",)), tmp_path / "b", workers=1).path
    journal = target.parent / "tiny.h5.journal"
    shutil.rmtree(journal, ignore_errors=True)
    shutil.copytree(source.parent / "tiny.h5.journal", journal)
    checked = _invoke("validate", target)
    assert checked.exit_code == 0 and checked.output.count("it belongs to another study") == 3, checked.output  # 3 named
    assert "4 journal entries ignored" in checked.output
    assert len(tidy_metrics(target)) == 3
    assert len(list((source.parent / "tiny.h5.journal").glob("*.json"))) == 4


def test_report_reads_a_study_whose_journal_holds_a_refused_record(tmp_path, monkeypatch):
    """A record of a setting the study does not have made `report` fail with an IndexError (found by
    an attack); it is now skipped, and the report is written from the cells that are the study's."""
    path = _journal_only(tmp_path, monkeypatch, seeds="0-0", methods=("c1",))
    extra = path.parent / "tiny.h5.journal" / "5-0-c1.json"
    shutil.copy(path.parent / "tiny.h5.journal" / "0-0-c1.json", extra)
    _reseal(extra, lambda r: r.update(setting=5))
    result = _invoke("report", "--results", tmp_path, "--out", tmp_path / "report", "--jobs", "1", "--quiet")
    assert result.exit_code == 0, result.output
