"""Bytes a reader trusts that HDF5 does not checksum: attributes of a run store, string columns and
attributes of a study store. Real single-bit flips in real files: each one that changes what a
reader reads is refused in one line; none passes as good data. Old stores (no seals) are read,
and `validate` says that their metadata is unverified.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import pytest
from typer.testing import CliRunner

from ilcforce import store
from ilcforce.cli.main import app
from ilcforce.store import StoreError
from ilcforce.store.seal import ATTRS_SEAL, STRINGS_SEAL
from ilcforce.store.study_read import StudyStoreError, read_tables

from storekit import path, write_run, writer  # noqa: F401 - path is a fixture
from test_study import small_study


def _flip(source: Path, target: Path, offset: int, bit: int) -> None:
    shutil.copy(source, target)
    with target.open("r+b") as raw:
        raw.seek(offset)
        byte = raw.read(1)[0]
        raw.seek(offset)
        raw.write(bytes([byte ^ (1 << bit)]))


def _occurrences(data: bytes, needle: bytes) -> list[int]:
    found, start = [], 0
    while (at := data.find(needle, start)) >= 0:
        found.append(at)
        start = at + 1
    return found


def test_every_bit_flip_in_the_stored_configuration_is_caught(path, tmp_path):
    """A flipped bit in config_json (`plant.m3` 0.5 -> 0.4 is one bit: found by an attack as c3.eta
    5.0 -> 4.0, after which a `--resume --set c3.eta=4` mixed two gains in one store) is refused by
    `validate` and by a resume, wherever HDF5 keeps the text."""
    write_run(path, 2)
    with h5py.File(path, "r") as handle:
        config = handle.attrs["config_json"]
    config = config.decode() if isinstance(config, bytes) else str(config)
    data = path.read_bytes()
    places = _occurrences(data, config.encode())
    assert places, "the configuration is stored as its text"
    changed = 0
    for k, start in enumerate(places):  # HDF5 may keep stale copies in freed space: only the read one counts
        at = start + config.index('"m3": 0.5') + len('"m3": 0.')
        for bit in range(8):
            broken = tmp_path / f"flip{k}-{bit}.h5"
            _flip(path, broken, at, bit)
            try:
                with h5py.File(broken, "r") as handle:
                    now = handle.attrs["config_json"]
            except (OSError, KeyError):
                now = None
            if now == config:
                continue
            changed += 1
            with pytest.raises(StoreError) as error:
                store.validate(broken)
            assert "\n" not in str(error.value)
            with pytest.raises(StoreError):
                with writer(broken, resume=True):
                    pass
    assert changed >= 8, "every bit of the read copy was flipped"


def test_bit_flips_across_the_metadata_never_pass_as_other_content(path, tmp_path):
    """Every bit of every attribute string of the store (units, descriptions, labels, the command,
    the configuration TOML): each flip either is caught, or leaves every attribute a reader reads as
    it was (the flip hit bytes nobody reads)."""
    write_run(path, 1)

    def attributes(file: Path) -> dict:
        found = {}
        with h5py.File(file, "r") as handle:
            def visit(name, item):
                for key, value in item.attrs.items():
                    found[(name, key)] = repr(value)
            visit("/", handle)
            handle.visititems(visit)
        return found

    original = attributes(path)
    data = path.read_bytes()
    targets = set()
    for needle in (b"kg m^2", b"N m", b"desired_torque", b"learned memory", b"[plant]"):
        for at in _occurrences(data, needle)[:3]:
            targets.add(at + 1)
    assert len(targets) >= 5
    for k, at in enumerate(sorted(targets)):
        for bit in (0, 5):
            broken = tmp_path / f"b{k}-{bit}.h5"
            _flip(path, broken, at, bit)
            try:
                store.validate(broken)
            except StoreError:
                continue
            assert attributes(broken) == original, f"flip at {at} bit {bit} changed an attribute undetected"


def test_a_store_without_seals_is_read_and_named_unverified(path):
    """A schema-2.0 store (written before attributes were sealed, and records bound) is accepted;
    `validate` says its metadata is unverified. A 2.1 store whose seal is gone is refused."""
    write_run(path, 2)
    with h5py.File(path, "a") as handle:
        def strip(name, item):
            for key in (ATTRS_SEAL, "binding_sha256", "store_id", "n_iterations_stored"):
                if key in item.attrs:
                    del item.attrs[key]
        strip("/", handle)
        handle.visititems(strip)
        handle.attrs["schema_version"] = "2.0"
    notes = store.validate(path)
    assert notes and notes[0].startswith("metadata unverified"), notes
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0 and "; metadata unverified:" in result.output, result.output
    with h5py.File(path, "a") as handle:
        handle.attrs["schema_version"] = "2.1"
    with pytest.raises(StoreError, match="carry no checksum"):
        store.validate(path)


@pytest.mark.parametrize("column, value", [("metrics/method", "c9"), ("metrics/status", "complede"),
                                           ("cells/state", "done "), ("settings/label", "x")])
def test_a_changed_string_in_a_study_store_is_refused(tmp_path, column, value):
    """A string column's value changed after writing (found by an attack: a flipped bit exported a
    method the study never ran, a status 'complede'): readers refuse the store in one line."""
    summary = run_small(tmp_path)
    with h5py.File(summary, "a") as handle:
        dataset = handle[column]
        dataset[0] = value
    with pytest.raises(StudyStoreError, match=f"the strings of /{column} do not match their checksum"):
        read_tables(summary)
    result = CliRunner().invoke(app, ["export", str(summary), "--out", str(tmp_path / "t.csv")])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output


def test_raw_bit_flips_in_a_study_store_strings_never_export_other_names(tmp_path):
    """One flipped bit in each stored "complete" and "c3" (the status and method columns, sessions,
    the study text): the table read back is the original or the read is refused."""
    path = run_small(tmp_path)
    original = read_tables(path)[1]
    data = path.read_bytes()
    places = [(at, 4) for at in _occurrences(data, b"complete")] + [(at, 0) for at in _occurrences(data, b"c3")]
    assert len(places) > 3
    refused = 0
    for k, (at, bit) in enumerate(places[:40]):
        broken = tmp_path / f"s{k}.h5"
        _flip(path, broken, at + 1 if bit else at + 1, bit)
        try:
            table = read_tables(broken)[1]
        except StudyStoreError:
            refused += 1
            continue
        assert table.equals(original), f"flip at {at} changed the table undetected"
    assert refused > 0


def test_a_study_store_without_seals_is_read(tmp_path):
    """A study store of schema 1.0 (no seals, digests or bindings) is read; the driver's next
    consolidation seals and binds it."""
    path = run_small(tmp_path)
    with h5py.File(path, "a") as handle:
        def strip(name, item):
            for key in (ATTRS_SEAL, STRINGS_SEAL, "data_sha256", "binding_sha256"):
                if key in item.attrs:
                    del item.attrs[key]
        strip("/", handle)
        handle.visititems(strip)
        handle.attrs["schema_version"] = "1.0"
    before = read_tables(path)[1]
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0 and "; strings and attributes unverified" in result.output, result.output
    from ilcforce.study import run_study

    run_study(small_study(seeds="0-1"), tmp_path, workers=1)  # one more seed: consolidates
    with h5py.File(path, "r") as handle:
        assert handle.attrs["schema_version"] == "1.3" and STRINGS_SEAL in handle["metrics/method"].attrs
        assert "data_sha256" in handle["metrics/force_error_rms"].attrs
    after = read_tables(path)[1]
    assert len(after) == 2 * len(before)


def _halve(handle, name):
    handle[name][0] = handle[name][0] / 2


def _seed_changed(handle, name):
    handle["cells/seed"][0] = 7


def _hard_link(handle, name):
    del handle["metrics/position_error_rms"]
    handle["metrics/position_error_rms"] = handle["metrics/force_error_rms"]


@pytest.mark.parametrize("edit", [_halve, _seed_changed, _hard_link])
def test_numeric_columns_edited_through_h5py_are_refused(tmp_path, edit):
    """An edit through h5py gets a recomputed Fletcher-32 for free, and may even keep the attribute
    seals right (an edit of data leaves attributes alone); the columns' digests refuse it."""
    path = run_small(tmp_path)
    with h5py.File(path, "a") as handle:
        edit(handle, "metrics/force_error_rms")
    for command in (["validate", str(path)], ["export", str(path), "--out", str(tmp_path / "t.csv")]):
        result = CliRunner().invoke(app, command)
        assert result.exit_code == 2 and "do not match their digest" in result.output, result.output
    assert not (tmp_path / "t.csv").exists()


def run_small(tmp_path: Path) -> Path:
    from ilcforce.study import run_study

    return run_study(small_study(seeds="0-0"), tmp_path, workers=1).path
