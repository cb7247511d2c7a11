"""Tuning figures: a method's objective against the trial number (``ilcforce tune``).

Draws on the Axes it is given and returns the artists, as every report figure does; the input is
:func:`ilcforce.tune.store.trials_frame`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.axes import Axes

from ilcforce.controllers import REGISTRY


def plot_tuning_history(ax: Axes, frame: pd.DataFrame, method: str) -> list:
    """The objective of each complete trial (dots), the best so far (a step line), failed trials
    as crosses at the bottom, and trial 0 (the experiment's own gains) ringed."""
    rows = frame[frame["method"] == method].sort_values("trial")
    spec = REGISTRY.get(method)
    color = spec.color if spec is not None else None
    label = spec.label if spec is not None else method
    done = rows[rows["state"] == "complete"]
    artists = [ax.plot(done["trial"], done["objective"], "o", ms=3, color=color, alpha=0.6, label=f"{label}: trial")[0],
               ax.step(rows["trial"], rows["best_so_far"], where="post", color=color, label=f"{label}: best so far")[0]]
    failed = rows[rows["state"] != "complete"]
    if len(failed):
        bottom = np.nanmin(rows["objective"]) if done.size else 0.0
        artists.append(ax.plot(failed["trial"], np.full(len(failed), bottom), "x", color="0.4",
                               label="failed (diverged or invalid)")[0])
    first = rows[(rows["trial"] == 0) & (rows["state"] == "complete")]
    if len(first):
        artists.append(ax.plot(first["trial"], first["objective"], "o", ms=8, mfc="none", color=color,
                               label="trial 0: the experiment's gains")[0])
    ax.set_xlabel("trial")
    ax.set_ylabel("objective (lower is better)")
    return artists
