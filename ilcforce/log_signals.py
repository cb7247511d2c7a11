"""An iteration's log signals, taken out of the compiled loop's log buffer (``ilcforce.simulate``).

:func:`signals` makes them; :class:`Later` makes them when first read, so that the simulation
thread can start the next iteration at once and the record's taker (the store's thread) spends
the 0.8 ms this takes after each loop of the paper's run (issue 12). The same arrays either way.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping

import numpy as np

from ilcforce.task import REF_FORCE, REF_POSITION


def signals(t_control: np.ndarray, log_every: int, log: np.ndarray, ref: np.ndarray, selection) -> dict:
    """The log signals of an iteration from the loop's log buffer (fresh per iteration)."""
    from ilcforce import loop

    out = {"time": t_control[::log_every].copy()}
    for name, col in loop.LOG_COLUMNS.items():
        out[name] = log[:, col:col + 2].copy()
    out["implicit_fallbacks"] = log[:, loop.LOG_FALLBACKS].copy()
    sel = np.asarray(selection, dtype=np.float64)
    ref_log = ref[::log_every]
    out["position_error"] = (1.0 - sel) * (ref_log[:, REF_POSITION:REF_POSITION + 2] - out["position"])  # eq. (6)
    out["force_error"] = sel * (ref_log[:, REF_FORCE:REF_FORCE + 2] - out["contact_force"])  # eq. (7)
    return out


class Later(Mapping):
    """A record's log signals, taken from the loop's buffer when first read (in any thread, once)."""

    def __init__(self, take: Callable[[], dict]) -> None:
        self._take, self._signals, self._lock = take, None, threading.Lock()

    def _all(self) -> dict:
        with self._lock:
            if self._signals is None:
                self._signals, self._take = self._take(), None
        return self._signals

    def __getitem__(self, name: str) -> np.ndarray:
        return self._all()[name]

    def __iter__(self):
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())

    def __reduce__(self):
        return dict, (self._all(),)
