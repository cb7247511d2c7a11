"""``ilcforce.open(path)``: a stored run read back as an object.

    run = ilcforce.open("results/paper/c3.h5")
    run.metrics                 # DataFrame, one row per iteration, units in .attrs["units"]
    run.iteration(19)           # IterationRecord (logs as arrays) ...
    run.iteration(-1)           # ... the last stored iteration (negative indices count from the end)
    run.iteration(19).to_pandas()   # ... or a DataFrame indexed by time, units in .attrs["units"]
    run.memory(19)              # learned memory after iteration 19 (DataFrame on the control grid)
    run.config                  # the Config the run was made with; run.config.c3 its C3 gains
    len(run), run[-1]           # number of stored iterations; an iteration by index
    for record in run: ...      # every stored iteration, in order

Every read goes through the store's readers (checked, checksummed, one-line StoreError). What a
run object shows is the file as it is now: a store that another process extends (``simulate
--resume``, a run still going) is read again when the file has changed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd

from ilcforce.records import IterationRecord
from ilcforce.store import access, safeio
from ilcforce.store.safeio import StoreError


@dataclass(frozen=True)
class StoredIteration(IterationRecord):
    """An :class:`IterationRecord` read from a store (``memory`` included), with :meth:`to_pandas`."""

    frame: pd.DataFrame | None = None

    def to_pandas(self) -> pd.DataFrame:
        """The logs as a DataFrame indexed by time (s); ``attrs["units"]`` maps column -> unit."""
        assert self.frame is not None
        return self.frame.copy()


class Run:
    """One stored run (one method of one experiment). Opens nothing until asked."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        access.validate(self.path)  # a damaged file fails here, in bounded time, with one line
        self._read: dict[str, tuple[tuple, Any]] = {}  # name -> (version of the file, value read)

    def _current(self, name: str, load: Callable[[], Any]) -> Any:
        """``load()``, read again only when the file has changed since (another process wrote it)."""
        try:
            version = safeio.file_key(self.path)
        except OSError:
            return load()  # gone or unreadable: the reader names the problem
        known = self._read.get(name)
        if known is None or known[0] != version:
            known = (version, load())
            self._read[name] = known
        return known[1]

    def __repr__(self) -> str:
        p = self.provenance
        return (f"<ilcforce run {p.get('experiment')}/{p.get('method')}: {len(self.iterations)} iterations, "
                f"{p.get('run_state')}, {self.path}>")

    @property
    def provenance(self) -> dict[str, Any]:
        """Root attributes: experiment, method, seed, git_commit, command, run_state, ..."""
        return self._current("provenance", lambda: access.read_provenance(self.path))

    @property
    def method(self) -> str:
        return str(self.provenance["method"])

    @property
    def experiment(self) -> str:
        return str(self.provenance["experiment"])

    @property
    def task_dimension(self) -> int:
        """n, the run's task axes and joints (2 or 3): its logs are (n_log, n), its task axes
        :func:`ilcforce.records.task_axes` of n."""
        return self._current("task_dimension", lambda: access.read_task_dimension(self.path))

    @property
    def iterations(self) -> list[int]:
        """Complete iterations, ascending."""
        return list(self._current("iterations", lambda: access.iterations(self.path)))

    @property
    def metrics(self) -> pd.DataFrame:
        """One row per iteration (index ``iteration``); ``attrs["units"]`` column -> unit."""
        return self._current("metrics", lambda: access.read_metrics(self.path)).copy()

    @property
    def config(self):
        """The run's configuration as a :class:`ilcforce.config.Config`."""
        from ilcforce.config_load import config_from_dict
        from ilcforce.samerun import stored_config

        return self._current("config", lambda: config_from_dict(stored_config(self.provenance)))

    @property
    def reference(self) -> pd.DataFrame:
        """The reference trajectories on the log grid (index ``time``, units in attrs)."""
        return self._current("reference", lambda: access.read_reference(self.path)).copy()

    def __len__(self) -> int:
        """The number of stored iterations."""
        return len(self.iterations)

    def __iter__(self):
        """Every stored iteration as a :class:`StoredIteration`, in order (those stored when the loop starts)."""
        for j in self.iterations:
            yield self.iteration(j)

    def __getitem__(self, j: int) -> StoredIteration:
        """``run[j]`` is ``run.iteration(j)``; IndexError (one line) for an iteration not stored."""
        number = self._number(j)
        if number not in self.iterations:
            raise IndexError(f"{self.path}: iteration {j} is not stored ({len(self)} stored)")
        return self.iteration(number)

    def _number(self, j: int) -> int:
        """The iteration number j, or for a negative j the stored iteration counted from the end
        (-1 the last), as Python indexes a list. StoreError (one line) if there are too few."""
        if isinstance(j, bool) or not isinstance(j, (int, np.integer)):
            raise TypeError(f"an iteration is an integer index, got {j!r}")
        if j >= 0:
            return int(j)
        stored = self.iterations
        if -j > len(stored):
            raise StoreError(f"{self.path}: iteration {j} is not stored ({len(stored)} iterations stored)")
        return stored[j]

    def iteration(self, j: int) -> StoredIteration:
        """Iteration ``j`` (negative: counted from the last stored, -1 the last): logs (arrays on the
        log grid), memory, status; ``.to_pandas()``."""
        j = self._number(j)
        frame = access.read_iteration(self.path, j)
        from ilcforce.records import log_signals

        log: dict[str, np.ndarray] = {"time": frame.index.to_numpy()}
        for signal, (axes, _unit, _description) in log_signals(self.task_dimension).items():
            if signal == "time":
                continue
            columns = [signal] if axes is None else [f"{signal}_{a}" for a in axes]
            values = frame[columns].to_numpy()
            log[signal] = values[:, 0] if axes is None else values
        info = access.read_memory_info(self.path, j)
        return StoredIteration(
            iteration=int(frame.attrs["iteration"]), status=str(frame.attrs["status"]),
            diverged_time=float(frame.attrs["diverged_time"]), diverged_reason=str(frame.attrs["diverged_reason"]),
            fallback_count=int(frame.attrs["fallback_count"]), log=log, memory=access.read_memory(self.path, j),
            memory_units={k: v["units"] for k, v in info.items()},
            memory_labels={k: tuple(v["columns"]) for k, v in info.items() if v["columns"]}, frame=frame)

    def memory(self, j: int) -> pd.DataFrame:
        """The learned memory after iteration ``j`` as a DataFrame on the control grid.

        One column per memory entry (a matrix gives one column per labelled entry, e.g.
        ``theta_hat_D11``); ``attrs["units"]`` column -> unit. A negative ``j`` counts from the
        last stored iteration (-1 the last).
        """
        j = self._number(j)
        arrays = access.read_memory(self.path, j)
        info = access.read_memory_info(self.path, j)
        time = access.read_control_time(self.path)
        data: dict[str, np.ndarray] = {}
        units: dict[str, str] = {}
        for name, values in arrays.items():
            if values.ndim == 1:
                data[name] = values
                units[name] = info[name]["units"]
            else:
                labels = info[name]["columns"] or [str(k) for k in range(values.shape[1])]
                for k, label in enumerate(labels):
                    data[f"{name}_{label}"] = values[:, k]
                    units[f"{name}_{label}"] = info[name]["units"]
        n = next(iter(data.values())).shape[0] if data else 0
        index = pd.Index(time if time is not None and time.shape[0] == n else np.arange(n), name="time")
        frame = pd.DataFrame(data, index=index)
        frame.attrs["units"] = units
        frame.attrs["iteration"] = int(j)
        return frame


def open_run(path: str | os.PathLike[str]) -> Run:
    """Open a stored run (see :class:`Run`); StoreError (one line) if it is not a valid store."""
    return Run(path)
