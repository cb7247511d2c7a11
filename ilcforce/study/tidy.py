"""The tidy metrics frame of a study store or of a run store, and its CSV export.

One row per (setting..., seed, method, iteration). Columns, in order: for a study with a settings
list (``[[study.settings]]``) ``setting_label`` (the setting's label), then the setting columns named
by their config key (e.g. ``simulation.sample_time``: the swept keys, or the union of the listed
settings' keys, each setting carrying its resolved value in every one; none for a study of one
setting), ``seed``, ``method``,
``iteration``, then the metric columns in the order of :func:`ilcforce.metrics.metric_order` (a 2-axis
study's :data:`~ilcforce.metrics.METRIC_COLUMNS`, a 3-axis one's :func:`~ilcforce.metrics.metric_columns`
of 3), then any further columns (a study's ``memory_norm_*``). A run store is the one-setting, one-seed
case. Failed cells have no rows (see :attr:`StudyResults.cells`).

Units. The frame :func:`tidy_metrics` returns carries them as ``frame.attrs["units"]`` (column -> unit) and
``frame.attrs["descriptions"]`` (column -> what it is); :func:`export` writes them beside the CSV in
a sidecar table ``<name>.units.csv`` (columns ``column``, ``unit``, ``description``, one row per
column of the CSV, in its order), so the CSV itself stays one header row that any reader takes.
Units are SI text (``"m"``, ``"N s^1/2"``), ``"1"`` for a dimensionless number (seed, iteration,
a count), ``""`` for text (method, status, a setting's label).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ilcforce.metrics import KNOWN_METRIC_COLUMNS, metric_order
from ilcforce.store.safeio import HDF5_SIGNATURE
from ilcforce.store.study import StudyStoreError, is_study_store, read_tables

_INT_COLUMNS = ("seed", "iteration", "fallback_count")
#: The tidy column holding a listed setting's label.
LABEL_COLUMN = "setting_label"


class ExportError(Exception):
    """A store that cannot be exported, or an output that may not be written; one line."""


@dataclass(frozen=True)
class StudyResults:
    """Everything a study store holds, as frames.

    Attributes
    ----------
    name, description : str
    study_toml : str
        The study file as it was run.
    sweep_keys : list of str
        The setting columns (config keys): the swept keys in grid order, after the union of the
        listed settings' keys when the study has a settings list.
    labelled : bool
        True for a study with a settings list: its settings are named (``settings["label"]``) and
        the tidy frames lead with a ``setting_label`` column.
    settings : DataFrame
        One row per setting: ``setting`` (index in the grid), ``label``, the swept keys' values,
        ``config_json`` (the resolved config; a cell's is this with ``experiment.seed`` = its seed).
    metrics : DataFrame
        The tidy metrics frame (module doc).
    cells : DataFrame
        One row per stored cell: swept keys, ``seed``, ``method``, ``state`` ("done" / "failed"),
        ``attempts``, ``message``, ``elapsed`` (s), ``worker``.
    sessions : list of dict
        Provenance of every run that wrote the store (command, scheduler, workers, versions).
    """

    name: str
    description: str
    study_toml: str
    sweep_keys: list
    labelled: bool
    settings: pd.DataFrame
    metrics: pd.DataFrame
    cells: pd.DataFrame
    sessions: list
    row_setting: np.ndarray  # the setting index of each row of ``metrics``

    def setting_metrics(self, setting: int) -> pd.DataFrame:
        """The tidy rows of one setting (``seed``, ``method``, ``iteration`` + metrics)."""
        frame = self.metrics[self.row_setting == int(setting)]
        return frame.drop(columns=self.leading_columns).reset_index(drop=True)

    @property
    def planned_cells(self) -> int | None:
        """The cells (settings x seeds x methods) the latest run set out to store; None for a store
        written before runs recorded it. Fewer stored cells than this: the run was stopped."""
        planned = [s["cells_planned"] for s in self.sessions if "cells_planned" in s]
        return int(planned[-1]) if planned else None

    @property
    def latest_study_toml(self) -> str:
        """The study file as the latest run read it (a rerun may add seeds or methods)."""
        from ilcforce.store.study_read import latest_study_toml

        return latest_study_toml(self.sessions, self.study_toml)

    @property
    def leading_columns(self) -> list[str]:
        """The tidy frame's setting columns: ``setting_label`` (settings list only), then the keys."""
        return [*([LABEL_COLUMN] if self.labelled else []), *self.sweep_keys]


def _order(frame: pd.DataFrame, leading: list[str], methods: list[str] | None = None) -> pd.DataFrame:
    metrics = [c for c in metric_order(frame.columns) if c != "iteration"]
    rest = sorted(c for c in frame.columns if c not in (*leading, "seed", "method", "iteration", *metrics))
    frame = frame[[*leading, "seed", "method", "iteration", *metrics, *rest]]
    for column in _INT_COLUMNS:
        if column in frame.columns and len(frame):
            frame[column] = frame[column].astype(np.int64)
    if "status" in frame.columns:
        frame["status"] = frame["status"].astype(str)
    return frame


def column_units(columns) -> tuple[dict[str, str], dict[str, str]]:
    """(units, descriptions) of the tidy columns ``columns`` (module doc); a column the tidy frame
    does not define (none in a frame this module makes) is left out of both."""
    from ilcforce.config_units import config_unit
    from ilcforce.controllers import REGISTRY

    memory_units = {name: unit for spec in REGISTRY.values() for name, (_a, _b, unit) in spec.memory_layout.items()}
    fixed = {LABEL_COLUMN: ("", "the setting's label (the study's [[study.settings]] entry)"),
             "seed": ("1", "random seed of the cell: the root of its disturbance and sensor noise draws"),
             "method": ("", "the method (an ilcforce --method name)")}
    units: dict[str, str] = {}
    descriptions: dict[str, str] = {}
    for column in columns:
        column = str(column)
        if column in fixed:
            units[column], descriptions[column] = fixed[column]
        elif column in KNOWN_METRIC_COLUMNS:
            units[column], descriptions[column] = KNOWN_METRIC_COLUMNS[column]
        elif (kind := next((k for k in _MEMORY_NORMS if column.startswith(k)), None)) is not None \
                and column.removeprefix(kind) in memory_units:
            name = column.removeprefix(kind)
            units[column] = memory_units[name]
            descriptions[column] = _MEMORY_NORMS[kind].format(name=name)
        else:
            try:
                units[column] = config_unit(column)
            except KeyError:
                continue
            descriptions[column] = "configuration value of the cell's setting (the config key it is named by)"
    return units, descriptions


#: the learned-memory norm columns a study stores (:func:`ilcforce.metrics.memory_norms`): prefix -> description
_MEMORY_NORMS = {
    "memory_norm_": "RMS over the control grid of the per-sample Euclidean norm of the learned memory {name} "
                    "after the iteration",
    "memory_settled_": "the same RMS from the settled time on (without the start mismatch at t = 0) of the learned "
                       "memory {name}",
    "memory_start_": "the Euclidean norm of the learned memory {name} at t = 0 alone",
}


def _with_units(frame: pd.DataFrame) -> pd.DataFrame:
    frame.attrs["units"], frame.attrs["descriptions"] = column_units(frame.columns)
    return frame


def units_path(out: Path | str) -> Path:
    """The units sidecar :func:`export` writes beside table ``out``: ``paper-mc.csv`` ->
    ``paper-mc.units.csv``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.units{out.suffix}")


def read_study(path: Path | str) -> StudyResults:
    """Read a study store (consolidated file plus journal); StudyStoreError if it is not one."""
    path = Path(path)
    header, raw, cells = read_tables(path)
    definition = json.loads(header.get("definition_json", "{}"))
    sweep_keys = list(definition.get("sweep_keys", []))
    labelled = "labels" in definition
    leading = [*([LABEL_COLUMN] if labelled else []), *sweep_keys]
    settings = header["settings"].copy()
    settings.insert(0, "setting", np.arange(len(settings), dtype=np.int64))
    values = [json.loads(v) for v in settings["values_json"]]
    for key in sweep_keys:
        settings[key] = [v.get(key) for v in values]
    settings = settings.drop(columns=["values_json"]).set_index("setting", drop=False)

    def with_setting_columns(frame: pd.DataFrame) -> pd.DataFrame:
        frame = frame.copy()
        index = frame["setting"].astype(np.int64).to_numpy() if len(frame) else np.zeros(0, np.int64)
        if labelled:
            frame[LABEL_COLUMN] = settings["label"].astype(str).to_numpy()[index] if len(frame) else []
        for key in sweep_keys:
            frame[key] = settings[key].to_numpy()[index] if len(frame) else []
        return frame

    from ilcforce.controllers import REGISTRY

    registered = list(REGISTRY)
    methods = sorted(set(raw["method"]) if len(raw) else (),
                     key=lambda m: (registered.index(m) if m in registered else len(registered), m))
    metrics = with_setting_columns(raw) if len(raw) else pd.DataFrame(columns=[*leading, "setting", "seed",
                                                                               "method", "iteration"])
    if len(metrics):
        order = {m: i for i, m in enumerate(methods)}
        metrics = metrics.assign(_m=metrics["method"].map(order)).sort_values(
            ["setting", "seed", "_m", "iteration"], kind="stable").drop(columns=["_m"])
    row_setting = metrics["setting"].to_numpy(dtype=np.int64) if len(metrics) else np.zeros(0, np.int64)
    metrics = _order(metrics.drop(columns=["setting"]), leading).reset_index(drop=True)
    if len(cells):
        cells = with_setting_columns(cells)
        cells = cells[[*leading, "setting", "seed", "method", "state", "attempts", "message", "elapsed",
                       "worker"]].sort_values(["setting", "seed", "method"]).reset_index(drop=True)
    return StudyResults(name=str(header.get("name", "")), description=str(header.get("description", "")),
                        study_toml=str(header.get("study_toml", "")), sweep_keys=sweep_keys, labelled=labelled,
                        settings=settings, metrics=metrics, cells=cells,
                        sessions=json.loads(header.get("sessions_json", "[]")), row_setting=row_setting)


def run_store_metrics(path: Path | str) -> pd.DataFrame:
    """The tidy frame of one run store (``seed``, ``method``, ``iteration`` + metric columns)."""
    from ilcforce import store

    provenance = store.read_provenance(path)
    frame = store.read_metrics(path).reset_index()
    frame.insert(0, "seed", int(provenance.get("seed", 0)))
    frame.insert(1, "method", str(provenance.get("method", Path(path).stem)))
    return _order(frame, []).reset_index(drop=True)


def tidy_metrics(path: Path | str) -> pd.DataFrame:
    """The tidy metrics frame of a study store or a run store (the Python API of ``ilcforce export``).

    ``frame.attrs["units"]`` maps each column to its unit and ``frame.attrs["descriptions"]`` to what
    it is (module doc). Raises ExportError (one line) for a missing, damaged or foreign file.
    """
    from ilcforce import store

    path = Path(path)
    if not path.exists():
        raise ExportError(f"{path} does not exist")
    if not path.is_file():
        raise ExportError(f"{path} is not a regular file")
    # units go on the frame handed out, not on the frames the report works on (pandas deep-copies
    # attrs at every operation)
    if is_study_store(path):
        try:
            return _with_units(read_study(path).metrics)
        except StudyStoreError as exc:
            raise ExportError(str(exc)) from None
    try:
        store.validate(path)
        return _with_units(run_store_metrics(path))
    except (store.StoreError, OSError, KeyError, ValueError) as exc:
        raise ExportError(" ".join(str(exc).split()) or f"{path}: not an ilcforce store") from None


def export(path: Path | str, out: Path | str, *, overwrite: bool = False) -> tuple[Path, int]:
    """Write the tidy metrics of ``path`` to ``out`` (``.csv``) and their units to
    :func:`units_path` (``<name>.units.csv``: ``column``, ``unit``, ``description``, one row per
    column of ``out``); returns (out, number of rows).

    Floats are written with Python's shortest round-trip representation, so reading the CSV back
    gives the stored values bit for bit. An existing ``out`` (or units file) is replaced only with
    ``overwrite`` and only if it is a regular file; each new file appears atomically (temporary
    name, rename), the units file first.
    """
    out = Path(out)
    if out.suffix.lower() != ".csv":
        hint = " (parquet would need pyarrow, which ilcforce does not install)" if out.suffix.lower() == ".parquet" else ""
        raise ExportError(f"--out {out}: only .csv is supported{hint}")
    sidecar = units_path(out)
    for target, what in ((out, f"--out {out}"), (sidecar, f"the units file {sidecar} of --out {out}")):
        if os.path.lexists(target):
            if target.is_symlink() or not target.is_file():
                raise ExportError(f"{what} exists and is not a regular file; refusing to replace it")
            if not overwrite:
                raise ExportError(f"{what} exists; pass --overwrite to replace it")
            _check_replaceable(Path(path), target)
    frame = tidy_metrics(path)
    if not out.parent.is_dir():
        raise ExportError(f"--out {out}: folder {out.parent} does not exist")
    units = pd.DataFrame({"column": [str(c) for c in frame.columns],
                          "unit": [frame.attrs["units"].get(str(c), "") for c in frame.columns],
                          "description": [frame.attrs["descriptions"].get(str(c), "") for c in frame.columns]})
    for table, target in ((units, sidecar), (frame, out)):
        tmp = target.with_name(f".{target.name}.tmp-{os.getpid()}")
        try:
            table.to_csv(tmp, index=False)
            os.replace(tmp, target)
        except OSError as exc:  # named by --out, not by the temporary file
            raise ExportError(f"--out {target}: {exc.strerror or exc}") from None
        finally:
            if tmp.exists():
                tmp.unlink()
    return out, len(frame)


def _check_replaceable(source: Path, out: Path) -> None:
    """--overwrite replaces a table, never the store being exported (under any of its names) nor any
    other HDF5 file: a store named ``*.csv`` was once replaced by its own export."""
    try:
        same = source.exists() and os.path.samefile(source, out)
    except OSError:
        same = False
    if same:
        raise ExportError(f"--out {out} is the store being exported ({source}); refusing to replace it")
    try:
        with out.open("rb") as handle:
            head = handle.read(len(HDF5_SIGNATURE))
    except OSError as exc:
        raise ExportError(f"--out {out} cannot be read: {exc.strerror or exc}") from None
    if head == HDF5_SIGNATURE:
        raise ExportError(f"--out {out} is an HDF5 file (a store?), not a table; refusing to replace it")
