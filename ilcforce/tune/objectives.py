"""What a trial scores: its two objectives from one seed's metrics rows, both minimised.

The **error** is ``log10(e_P / 1 mm) + log10(e_F / 1 N)`` of the RMS error norms averaged over the scored
iterations (``iterations - score_last .. iterations - 1``): a tenfold smaller error of either kind counts
the same, and the scales only shift the value ("position" or "force" keep one term). The **chattering**
is ``log10(max over the task's axes a of H_a / cap_a)`` of the settled H per task axis over the same
iterations (``max(H_x / cap_x, H_y / cap_y)`` on the planar task, H_u, H_v, H_n on a 3-axis one: the axes
are :func:`ilcforce.records.task_axes`), where the cap is the reference method's settled H per axis: 0 is
as much chattering as the reference, -1 a tenth. The hypervolume of a front is measured up to
:data:`HV_REFERENCE` in these units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: The chattering objectives there are: settled H per task axis against the cap (why H and not the control
#: effort: H is what the paper and the claims call chattering, and per axis it cannot trade one axis for the other).
CHATTERING = ("settled-H",)
#: Hypervolume reference point (error, chattering) in the objectives' units: e_P = 1 mm with e_F = 10 N
#: (or their product), and 10x the cap's chattering. A point beyond it adds nothing to the front's volume.
HV_REFERENCE = (1.0, 1.0)
#: objective name -> (position weight, force weight) of log10(e_P / 1 mm) and log10(e_F / 1 N)
OBJECTIVES = {"both": (1.0, 1.0), "position": (1.0, 0.0), "force": (0.0, 1.0)}
#: Scales of the objective's logarithms (they shift it by a constant; they make it readable).
POSITION_SCALE = 1e-3  # m
FORCE_SCALE = 1.0  # N


def settled_column(axis: str) -> str:
    """The metrics column of the settled H along task axis ``axis``: ``chattering_task_x_settled``."""
    return f"chattering_task_{axis}_settled"


def scored_means(rows: list[dict], tuning) -> dict[str, float] | None:
    """The means over the scored iterations (``iterations - score_last .. iterations - 1``) of the RMS
    error norms (``e_p``, ``e_f``) and the settled H per axis of the task (``h_x``, ``h_y``, or ``h_u``,
    ``h_v``, ``h_n``: ``tuning.axes``) of one seed's rows; None if the cell diverged anywhere or did not
    run the scored horizon."""
    if len(rows) < tuning.iterations or any(r["status"] != "complete" for r in rows[:tuning.iterations]):
        return None
    scored = rows[tuning.iterations - tuning.score_last:tuning.iterations]
    keys = {"e_p": "position_error_rms", "e_f": "force_error_rms",
            **{f"h_{axis}": settled_column(axis) for axis in tuning.axes}}
    return {k: sum(float(r[c]) for r in scored) / len(scored) for k, c in keys.items()}


def error_value(e_p: float, e_f: float, objective: str) -> float | None:
    """The error objective: ``log10(e_P / 1 mm) + log10(e_F / 1 N)`` (weights of ``objective``)."""
    wp, wf = OBJECTIVES[objective]
    value = 0.0
    if wp:
        value += wp * math.log10(max(e_p, 1e-300) / POSITION_SCALE)
    if wf:
        value += wf * math.log10(max(e_f, 1e-300) / FORCE_SCALE)
    return value if math.isfinite(value) else None


def chattering_over(h: Sequence[float], cap: Sequence[float]) -> float | None:
    """The chattering objective: ``log10(max over the task's axes a of H_a / cap_a)`` (0: the cap's
    chattering), ``h`` and ``cap`` one value per task axis, in the order of the axes."""
    if len(h) != len(cap):
        raise ValueError(f"H has {len(h)} axes and the cap {len(cap)}")
    value = math.log10(max(max(h_a, 1e-300) / cap_a for h_a, cap_a in zip(h, cap)))
    return value if math.isfinite(value) else None


def chattering_formula(axes: tuple[str, ...]) -> str:
    """The chattering objective's ratio as text: ``max(H_x / cap_x, H_y / cap_y)`` on the planar task."""
    return f"max({', '.join(f'H_{a} / cap_{a}' for a in axes)})"


def per_axis_text(axes: tuple[str, ...], values) -> str:
    """Settled H per task axis as text, ``values`` in the order of ``axes``: ``H_x 0.012 N, H_y 0.3 N``."""
    return ", ".join(f"H_{a} {v:.3g} N" for a, v in zip(axes, values, strict=True))
