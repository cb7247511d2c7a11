"""Records bound to their store and their place (issue 46, items 5-8): a record spliced from another
store with plain h5py or a JSON editor, every checksum recomputed that the docs describe (HDF5's
Fletcher-32, the CRC-32s of the data and of the attributes, a study column's digest as schema 1.2
made it, a JSON record's sha256), is refused by ``validate`` in one line with exit code 2.

Each forger's edit here uses h5py or json and, for the checksums, the documented formulas (the seal
module's functions compute exactly those). What none of this stops, and the docs say so, is a forger
who recomputes the binding too (docs/store-format.md, "What protects each byte").
"""

from __future__ import annotations

import json
import shutil
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.store.seal import seal_attrs

SHORT = ["--set", "reference.duration=0.2"]


def run_cli(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def refused(path: Path, *words: str) -> str:
    """`validate path` exits 2 with one line naming the file (and ``words``); returns the line."""
    result = run_cli("validate", path)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and str(path) in lines[0], result.output
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


# -- run stores ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[int, Path]:
    """Two 5-iteration C3 runs of the same experiment, seeds 0 and 7, made by `ilcforce simulate`."""
    folder = tmp_path_factory.mktemp("runs")
    out = {}
    for seed in (0, 7):
        out[seed] = folder / f"seed{seed}.h5"
        result = run_cli("simulate", "-m", "c3", "-n", "5", "--out", out[seed], "--set", f"experiment.seed={seed}",
                         *SHORT)
        assert result.exit_code == 0, result.output
        assert run_cli("validate", out[seed]).exit_code == 0
    return out


@pytest.fixture
def copies(runs, tmp_path) -> tuple[Path, Path]:
    """Fresh copies of the seed-0 (the victim) and seed-7 (the donor) stores."""
    victim, donor = tmp_path / "c3.h5", tmp_path / "donor.h5"
    shutil.copyfile(runs[0], victim)
    shutil.copyfile(runs[7], donor)
    return victim, donor


def splice_iteration(target: h5py.File, source: h5py.File, j: int) -> None:
    """Issue 46 item 5: /iterations/<j> of ``source`` copied over the target's, and its /metrics row."""
    name = f"iterations/{j:04d}"
    del target[name]
    source.copy(source[name], target["iterations"], name=f"{j:04d}")
    rows_source = list(source["metrics/iteration"][()]).index(j)
    rows_target = list(target["metrics/iteration"][()]).index(j)
    for column in target["metrics"]:
        target["metrics"][column][rows_target] = source["metrics"][column][rows_source]


def test_an_iteration_spliced_from_another_seed_is_refused_and_not_resumed(copies):
    """Item 5 as filed: iteration 3 and its metrics row of a seed-7 store copied into a seed-0 store
    with plain h5py (HDF5 recomputes its own checksums, the group brings its CRC-32s along). Before,
    `validate` said ok and `--resume` continued from the spliced memory."""
    victim, donor = copies
    with h5py.File(victim, "r") as handle:
        assert int(handle.attrs["seed"]) == 0
        assert "binding_sha256" in handle["iterations/0003"].attrs
    with h5py.File(victim, "a") as target, h5py.File(donor, "r") as source:
        splice_iteration(target, source, 3)
    with h5py.File(victim, "r") as handle, h5py.File(donor, "r") as source:  # the splice took
        np.testing.assert_array_equal(handle["iterations/0003/memory/theta_hat"][()],
                                      source["iterations/0003/memory/theta_hat"][()])
    refused(victim, "/iterations/0003", "not bound to this store")
    before = victim.read_bytes()
    result = run_cli("simulate", "-m", "c3", "-n", "6", "--out", victim, "--resume", *SHORT)
    assert result.exit_code == 2 and "/iterations/0003" in result.output, result.output
    assert victim.read_bytes() == before


def _forge_crc(group: h5py.Group, relative: str) -> None:
    """Recompute the documented CRC-32 of ``group/relative`` in the group's crc32 attribute."""
    names = [n.decode() if isinstance(n, bytes) else str(n) for n in group.attrs["crc32_datasets"]]
    sums = np.array(group.attrs["crc32"], dtype=np.uint32)
    if relative not in names:
        names.append(relative)
        sums = np.append(sums, np.uint32(0))
    sums[names.index(relative)] = zlib.crc32(np.ascontiguousarray(group[relative][()], dtype=np.float64).data)
    group.attrs["crc32_datasets"] = names
    group.attrs["crc32"] = sums


def _memory_dataset(victim: h5py.File, donor: h5py.File) -> None:
    """One memory dataset of the donor's iteration 3 over the victim's, its CRC-32 and seals recomputed."""
    group = victim["iterations/0003"]
    del group["memory/theta_hat"]
    donor.copy(donor["iterations/0003/memory/theta_hat"], group["memory"], name="theta_hat")
    _forge_crc(group, "memory/theta_hat")
    seal_attrs(group)


def _extra_dataset(victim: h5py.File, donor: h5py.File) -> None:
    """A dataset the iteration never had, listed in its checksums."""
    group = victim["iterations/0003"]
    donor.copy(donor["iterations/0003/memory/alpha_hat"], group["memory"], name="alpha_hat_2")
    _forge_crc(group, "memory/alpha_hat_2")
    seal_attrs(group)


def _dropped_dataset(victim: h5py.File, donor: h5py.File) -> None:
    """A memory dataset removed (the resume would start without it)."""
    del victim["iterations/0003/memory/alpha_hat"]


def _moved_within(victim: h5py.File, donor: h5py.File) -> None:
    """Iterations 3 and 4 of the same store swapped, each group's number attribute fixed and resealed."""
    victim.move("iterations/0003", "iterations/tmp")
    victim.move("iterations/0004", "iterations/0003")
    victim.move("iterations/tmp", "iterations/0004")
    for j in (3, 4):
        group = victim[f"iterations/{j:04d}"]
        group.attrs["iteration"] = j
        seal_attrs(group)


def _last_removed(victim: h5py.File, donor: h5py.File) -> None:
    """The last iteration deleted and the run marked partial, the root's seal recomputed."""
    del victim["iterations/0004"]
    victim.attrs["run_state"] = "partial"
    seal_attrs(victim)


def _all_iterations(victim: h5py.File, donor: h5py.File) -> None:
    """Every iteration and the whole /metrics of the donor."""
    for name in ("iterations", "metrics"):
        del victim[name]
        donor.copy(donor[name], victim, name=name)


def _identity_taken(victim: h5py.File, donor: h5py.File) -> None:
    """The donor's store_id over the victim's, the root's seal recomputed."""
    victim.attrs["store_id"] = donor.attrs["store_id"]
    seal_attrs(victim)


def _seed_claimed(victim: h5py.File, donor: h5py.File) -> None:
    """The victim claims the donor's seed (its data stays seed 0's)."""
    victim.attrs["seed"] = donor.attrs["seed"]
    seal_attrs(victim)


def _config_changed(victim: h5py.File, donor: h5py.File) -> None:
    """A gain the results depend on changed in the stored configuration, the root's seal recomputed."""
    config = json.loads(victim.attrs["config_json"])
    config["c3"]["eta"] = float(config["c3"]["eta"]) * 2
    victim.attrs["config_json"] = json.dumps(config)
    seal_attrs(victim)


def _reference_copied(victim: h5py.File, donor: h5py.File) -> None:
    """/reference of another store (its data happens to be equal: same experiment)."""
    del victim["reference"]
    donor.copy(donor["reference"], victim, name="reference")


def _reference_edited(victim: h5py.File, donor: h5py.File) -> None:
    """A value of the reference changed (Fletcher-32 is recomputed by HDF5)."""
    dataset = victim["reference/force_desired"]
    data = dataset[()]
    data[3, 1] *= 1.5
    dataset[...] = data


def _downgraded(victim: h5py.File, donor: h5py.File) -> None:
    """The splice, then the store relabelled schema 2.1 (unbound) with its root's seal recomputed."""
    splice_iteration(victim, donor, 3)
    victim.attrs["schema_version"] = "2.1"
    seal_attrs(victim)


def _downgraded_clean(victim: h5py.File, donor: h5py.File) -> None:
    """As _downgraded, and every binding and the identity removed, every seal recomputed: the forger has
    then recomputed what the docs describe, binding included (out of scope): the store reads as an
    unbound 2.1 store, and validate says so."""
    _downgraded(victim, donor)
    for name in ("store_id", "n_iterations_stored"):
        del victim.attrs[name]
    seal_attrs(victim)
    for group in [victim["reference"], *victim["iterations"].values()]:
        del group.attrs["binding_sha256"]
        seal_attrs(group)


def _hard_linked_within(victim: h5py.File, donor: h5py.File) -> None:
    """Iteration 3's memory made a hard link to iteration 2's, its CRC-32 and seal recomputed."""
    group = victim["iterations/0003"]
    del group["memory/theta_hat"]
    group["memory/theta_hat"] = victim["iterations/0002/memory/theta_hat"]
    _forge_crc(group, "memory/theta_hat")
    seal_attrs(group)


def _external_link(victim: h5py.File, donor: h5py.File) -> None:
    """Iteration 3 an HDF5 external link to the donor's iteration 3 (read through, from the other file)."""
    del victim["iterations/0003"]
    victim["iterations/0003"] = h5py.ExternalLink(donor.filename, "/iterations/0003")


def _soft_link(victim: h5py.File, donor: h5py.File) -> None:
    """Iteration 3 a soft link to iteration 2 of the same store."""
    del victim["iterations/0003"]
    victim["iterations/0003"] = h5py.SoftLink("/iterations/0002")


def _memory_edited(victim: h5py.File, donor: h5py.File) -> None:
    """Not a splice: the learned memory of iteration 4 (the one --resume starts from) scaled in place,
    its CRC-32 and seals recomputed as documented; the binding covers the CRC-32s."""
    group = victim["iterations/0004"]
    group["memory/alpha_hat"][...] = group["memory/alpha_hat"][()] * 2
    _forge_crc(group, "memory/alpha_hat")
    seal_attrs(group)


def _external_reference(victim: h5py.File, donor: h5py.File) -> None:
    """One reference signal an external link to the donor's (before, validate read the other file and said ok)."""
    del victim["reference/force_desired"]
    victim["reference/force_desired"] = h5py.ExternalLink(donor.filename, "/reference/force_desired")


def _appended(victim: h5py.File, donor: h5py.File) -> None:
    """The donor's iteration 4 appended as the victim's iteration 5, the count, its number and every seal
    recomputed (the run asked for 6)."""
    donor.copy(donor["iterations/0004"], victim["iterations"], name="0005")
    group = victim["iterations/0005"]
    group.attrs["iteration"] = 5
    seal_attrs(group)
    victim.attrs["n_iterations_stored"] = 6
    victim.attrs["n_iterations_requested"] = 6
    seal_attrs(victim)


@pytest.mark.parametrize("forge", [_memory_dataset, _extra_dataset, _dropped_dataset, _moved_within, _last_removed,
                                   _all_iterations, _identity_taken, _seed_claimed, _config_changed, _reference_copied,
                                   _reference_edited, _downgraded, _hard_linked_within, _external_link, _soft_link,
                                   _external_reference, _appended, _memory_edited])
def test_splice_variants_of_a_run_store_are_refused(copies, forge):
    victim, donor = copies
    with h5py.File(victim, "a") as target, h5py.File(donor, "r") as source:
        forge(target, source)
    refused(victim)


def test_a_store_stripped_of_its_bindings_reads_as_unbound_and_says_so(copies):
    """The limit, stated in the docs: a forger who removes every binding and recomputes every seal makes
    a store that reads as one of schema 2.1; validate accepts it only with the note that its records are
    not bound (no store ilcforce writes now is unbound)."""
    victim, donor = copies
    with h5py.File(victim, "a") as target, h5py.File(donor, "r") as source:
        _downgraded_clean(target, source)
    result = run_cli("validate", victim)
    assert result.exit_code == 0 and "records not bound to the store (schema 2.1" in result.output, result.output


def _unbind(handle: h5py.File) -> None:
    """Make ``handle`` a store as schema 2.1 wrote it: no identity, count or bindings, seals recomputed."""
    handle.attrs["schema_version"] = "2.1"
    for name in ("store_id", "n_iterations_stored"):
        del handle.attrs[name]
    seal_attrs(handle)
    for group in [handle["reference"], *handle["iterations"].values()]:
        del group.attrs["binding_sha256"]
        seal_attrs(group)


def test_splices_between_bound_and_unbound_stores(copies):
    """An iteration of an unbound (2.1) store spliced into a bound one is refused (it has no binding); a
    bound one spliced into an unbound store is refused too (it carries what 2.1 has not)."""
    victim, donor = copies
    with h5py.File(donor, "a") as handle:
        _unbind(handle)
    assert "records not bound" in run_cli("validate", donor).output
    spliced = victim.with_name("spliced.h5")
    shutil.copyfile(victim, spliced)
    with h5py.File(spliced, "a") as target, h5py.File(donor, "r") as source:
        splice_iteration(target, source, 3)
    refused(spliced, "/iterations/0003", "has no binding_sha256")
    with h5py.File(donor, "a") as target, h5py.File(victim, "r") as source:
        splice_iteration(target, source, 3)
    refused(donor, "/iterations/0003 carries a binding")


def test_an_unbound_store_resumes_unbound(copies):
    """A store of schema 2.1 (no binding: written before) is resumed as it is, its new iterations unbound,
    and still validates with its note."""
    victim, _donor = copies
    with h5py.File(victim, "a") as handle:
        del handle["iterations/0004"]
        handle.attrs["run_state"] = "partial"
        _unbind(handle)
    result = run_cli("simulate", "-m", "c3", "-n", "6", "--out", victim, "--resume", *SHORT)
    assert result.exit_code == 0, result.output
    result = run_cli("validate", victim)
    assert result.exit_code == 0 and "6 iterations" in result.output and "records not bound" in result.output
    with h5py.File(victim, "r") as handle:
        assert "binding_sha256" not in handle["iterations/0005"].attrs


def test_a_resumed_store_stays_bound(copies):
    """A bound store resumed with more iterations: the new ones are bound with the same key (the
    configuration's iteration count is not part of it)."""
    victim, _donor = copies
    result = run_cli("simulate", "-m", "c3", "-n", "7", "--out", victim, "--resume", *SHORT)
    assert result.exit_code == 0, result.output
    result = run_cli("validate", victim)
    assert result.exit_code == 0 and "7 iterations" in result.output and "not bound" not in result.output
    with h5py.File(victim, "r") as handle:
        assert int(handle.attrs["n_iterations_stored"]) == 7


# -- study stores -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def studies(tmp_path_factory) -> dict[float, Path]:
    """The same small study run at noise.scale 1 and at 3 (two results folders), by the study driver."""
    from ilcforce.study import build_study, run_study

    out = {}
    for scale in (1.0, 3.0):
        folder = tmp_path_factory.mktemp(f"scale{scale:g}")
        table = {"name": "tiny", "seeds": "0-1", "methods": ["c1", "c3"],
                 "set": {"experiment.iterations": 3, "reference.duration": 0.2, "noise.scale": scale}}
        out[scale] = run_study(build_study({"study": table}), folder, workers=1).path
        assert run_cli("validate", out[scale]).exit_code == 0
    return out


@pytest.fixture
def study_copies(studies, tmp_path) -> tuple[Path, Path]:
    victim, donor = tmp_path / "tiny.h5", tmp_path / "other.h5"
    shutil.copyfile(studies[1.0], victim)
    shutil.copyfile(studies[3.0], donor)
    return victim, donor


def _copy_groups(victim: h5py.File, donor: h5py.File, *names: str) -> None:
    for name in names:
        del victim[name]
        donor.copy(donor[name], victim, name=name)


def test_a_study_table_copied_from_another_study_is_refused(study_copies, tmp_path):
    """Item 6 as filed: /metrics and /cells of the study at noise.scale 3 copied into the one at 1 with
    h5py. The columns' digests named their path alone, so they held; validate said ok and export wrote
    the other study's numbers."""
    victim, donor = study_copies
    with h5py.File(victim, "a") as target, h5py.File(donor, "r") as source:
        assert not np.array_equal(target["metrics/force_error_rms"][()], source["metrics/force_error_rms"][()])
        _copy_groups(target, source, "metrics", "cells")
    refused(victim, "/metrics/", "not bound to this study", "copied from another study")
    out = tmp_path / "t.csv"
    result = run_cli("export", victim, "--out", out)
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert not out.exists()


def _digest_as_documented_before(dataset: h5py.Dataset) -> None:
    """The column's digest as documented (sha256 over its path and values), recomputed."""
    from ilcforce.store.seal import data_digest

    dataset.attrs["data_sha256"] = data_digest(dataset.name, dataset[()])
    seal_attrs(dataset)


def _one_numeric_column(victim: h5py.File, donor: h5py.File) -> None:
    del victim["metrics/force_error_rms"]
    donor.copy(donor["metrics/force_error_rms"], victim["metrics"], name="force_error_rms")


def _one_string_column(victim: h5py.File, donor: h5py.File) -> None:
    """A string column whose values are the same in both studies (the methods): only its place differs."""
    assert list(victim["metrics/method"].asstr()[()]) == list(donor["metrics/method"].asstr()[()])
    del victim["metrics/method"]
    donor.copy(donor["metrics/method"], victim["metrics"], name="method")


def _cells_only(victim: h5py.File, donor: h5py.File) -> None:
    _copy_groups(victim, donor, "cells")


def _settings_copied(victim: h5py.File, donor: h5py.File) -> None:
    _copy_groups(victim, donor, "settings")


def _columns_swapped(victim: h5py.File, donor: h5py.File) -> None:
    """Two columns of the same study swapped (each its own digest: the path is bound)."""
    victim.move("metrics/force_error_rms", "metrics/tmp")
    victim.move("metrics/position_error_rms", "metrics/force_error_rms")
    victim.move("metrics/tmp", "metrics/position_error_rms")


def _old_digests_recomputed(victim: h5py.File, donor: h5py.File) -> None:
    """The copy, every numeric column's documented digest recomputed (it was right already: the path is
    the same; the binding is not)."""
    _copy_groups(victim, donor, "metrics", "cells")
    for group in ("metrics", "cells"):
        for dataset in victim[group].values():
            if h5py.check_string_dtype(dataset.dtype) is None:
                _digest_as_documented_before(dataset)


def _study_id_taken(victim: h5py.File, donor: h5py.File) -> None:
    """The copy, and the donor's study_id over the victim's, the root's seal recomputed: the
    definition (noise.scale 1) still differs from the one the columns are bound to."""
    _copy_groups(victim, donor, "metrics", "cells")
    victim.attrs["study_id"] = donor.attrs["study_id"]
    seal_attrs(victim)


def _cell_rows_swapped(victim: h5py.File, donor: h5py.File) -> None:
    """Two cells' rows exchanged within the study: the first and last metric rows of every numeric column."""
    for dataset in victim["metrics"].values():
        if h5py.check_string_dtype(dataset.dtype) is None and dataset.shape[0] > 1:
            data = dataset[()]
            data[[0, -1]] = data[[-1, 0]]
            dataset[...] = data


def _cell_rows_swapped_resealed(victim: h5py.File, donor: h5py.File) -> None:
    """As _cell_rows_swapped, every column's documented digest recomputed: the binding covers the digest."""
    _cell_rows_swapped(victim, donor)
    for dataset in victim["metrics"].values():
        if h5py.check_string_dtype(dataset.dtype) is None:
            _digest_as_documented_before(dataset)


def _external_column(victim: h5py.File, donor: h5py.File) -> None:
    """A column an external link to the other study's (its digest, over the same path, held before)."""
    del victim["metrics/force_error_rms"]
    victim["metrics/force_error_rms"] = h5py.ExternalLink(donor.filename, "/metrics/force_error_rms")


@pytest.mark.parametrize("forge", [_one_numeric_column, _one_string_column, _cells_only, _settings_copied,
                                   _columns_swapped, _old_digests_recomputed, _study_id_taken, _cell_rows_swapped,
                                   _cell_rows_swapped_resealed, _external_column])
def test_splice_variants_of_a_study_store_are_refused(study_copies, forge):
    victim, donor = study_copies
    with h5py.File(victim, "a") as target, h5py.File(donor, "r") as source:
        forge(target, source)
    refused(victim)


def test_a_study_store_of_schema_1_2_is_read_unbound_and_bound_by_the_next_run(study_copies, tmp_path):
    """A store written before bindings (schema 1.2: no binding_sha256) is read with a note; the next run
    of its study binds it. A 1.2 store that carries bindings was altered (or continued by an older
    ilcforce) and is refused."""
    from ilcforce.study import build_study, run_study

    victim, donor = study_copies
    for path in (victim, donor):
        with h5py.File(path, "a") as handle:
            for group in ("settings", "metrics", "cells"):
                for dataset in handle[group].values():
                    if path == victim:
                        del dataset.attrs["binding_sha256"]
                        seal_attrs(dataset)
            handle.attrs["schema_version"] = "1.2"
            seal_attrs(handle)
    result = run_cli("validate", victim)
    assert result.exit_code == 0 and "columns not bound to the study (schema 1.2" in result.output, result.output
    refused(donor, "carries a binding, which its schema 1.2 does not have")
    results = tmp_path / "again"
    (results / "studies").mkdir(parents=True)
    shutil.copyfile(victim, results / "studies" / "tiny.h5")
    table = {"name": "tiny", "seeds": "0-2", "methods": ["c1", "c3"],
             "set": {"experiment.iterations": 3, "reference.duration": 0.2, "noise.scale": 1.0}}
    path = run_study(build_study({"study": table}), results, workers=1).path
    result = run_cli("validate", path)
    assert result.exit_code == 0 and "not bound" not in result.output and "6 done" in result.output, result.output
    with h5py.File(path, "r") as handle:
        assert handle.attrs["schema_version"] == "1.3" and "binding_sha256" in handle["metrics/method"].attrs


# -- what the docs say is checksummed ------------------------------------------------------------------


def test_the_docs_say_how_each_dataset_is_checksummed(runs, studies):
    """Item 15: docs/store-format.md said every dataset is Fletcher-32 checksummed; an iteration's log and
    memory are not (they carry CRC-32s in their group). Every dataset of a run and a study store made
    by the CLI and the driver is checksummed the way the docs say, and the docs say no other."""
    docs = (Path(__file__).resolve().parents[1] / "docs" / "store-format.md").read_text(encoding="utf-8")
    flat = " ".join(docs.split())
    assert "every dataset is Fletcher-32" not in flat and "every dataset | HDF5 Fletcher-32" not in flat
    assert ("HDF5's Fletcher-32 filter on a run's reference, control grid and `/metrics` and on a study's numeric "
            "columns" in flat)
    assert ("a CRC-32 per dataset in the iteration group's `crc32` attribute, in the order of its "
            "`crc32_datasets`, for a run iteration's log and memory datasets" in flat)
    assert "`strings_crc32` on a study's string columns" in flat
    with h5py.File(runs[0], "r") as handle:
        seen = {"fletcher": set(), "crc": set()}

        def visit(name: str, item) -> None:
            if not isinstance(item, h5py.Dataset):
                return
            top = name.split("/")[0]
            if top == "iterations":
                group = handle["/".join(name.split("/")[:2])]
                listed = [n.decode() if isinstance(n, bytes) else str(n) for n in group.attrs["crc32_datasets"]]
                assert not item.fletcher32 and name.split("/", 2)[2] in listed, name
                seen["crc"].add(name.split("/")[2])
            else:
                assert item.fletcher32, name
                seen["fletcher"].add(top)

        handle.visititems(visit)
        assert seen == {"fletcher": {"reference", "control_time", "metrics"}, "crc": {"log", "memory"}}
    with h5py.File(studies[1.0], "r") as handle:
        for group in ("settings", "metrics", "cells"):
            for name, dataset in handle[group].items():
                if h5py.check_string_dtype(dataset.dtype) is None:
                    assert dataset.fletcher32 and "data_sha256" in dataset.attrs, f"{group}/{name}"
                else:
                    assert not dataset.fletcher32 and "strings_crc32" in dataset.attrs, f"{group}/{name}"
                assert "binding_sha256" in dataset.attrs, f"{group}/{name}"


def test_the_docs_say_what_a_json_seal_covers():
    """Item 8: the docs name the canonical form the seal covers, and it is the one the code hashes."""
    from ilcforce.store import records

    docs = " ".join((Path(__file__).resolve().parents[1] / "docs" / "store-format.md").read_text(encoding="utf-8").split())
    formula = 'json.dumps(record, sort_keys=True, separators=(",", ":"), allow_nan=True)'
    assert "sha256 (hex) over the canonical JSON of the record as parsed" in docs and formula in docs
    assert "a key named twice in one object" in docs
    sample = {"z": [1.5, float("nan"), None], "a": "é\n", "m": {"y": 1, "b": True}}
    canonical = json.dumps(sample, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()
    import hashlib

    assert records.checksum(sample) == hashlib.sha256(canonical).hexdigest()
