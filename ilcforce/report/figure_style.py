"""What every report figure shares: each method's colour and label (from the method registry, so a method
looks the same in every figure), the style file, and the y-range helpers that keep the t = 0 start mismatch
and the legends off the data. The paper's figures are :mod:`ilcforce.report.figures`; the studies', the
calibration's, the claim map's and the long runs' draw with these too."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping, Sequence
from importlib import resources

import matplotlib.style
import numpy as np
from matplotlib.axes import Axes

from ilcforce.controllers import REGISTRY

#: Colours and labels come from the method registry (``MethodSpec.color``, ``.label``) and stay with
#: the method across every figure ("C<n>" is the n-th colour of the style's cycle).


def method_color(method: str) -> str | None:
    """The method's colour in every figure (None for a name the registry does not hold)."""
    spec = REGISTRY.get(method)
    return spec.color if spec is not None else None


def method_text(method: str, labels: Mapping[str, str] | None = None) -> str:
    """The method's label in a figure: ``labels[method]`` where given, else the registry's."""
    if labels and method in labels:
        return labels[method]
    spec = REGISTRY.get(method)
    return spec.label if spec is not None else method


def method_label(method: str) -> str:
    """The method's plain figure label (the report appends law differences and flags)."""
    return method_text(method)


#: Time from which the y range of input plots is set: the t = 0 start mismatch stays off scale.
RANGE_FROM = 0.02


#: Free band above the data of an input panel, as a fraction of the data's range: the legend and the
#: "off scale" note stand in it, so neither covers a sample (the signals fill their whole range).
HEADROOM = 0.45
#: The same band sized to the legend it holds: this much per legend row, plus HEADROOM_BASE (a fixed
#: 0.45 left a panel 40% empty above a one-row legend; Fig. 7 (a) ran to 50 N for data under 32 N).
HEADROOM_PER_ROW, HEADROOM_BASE = 0.1, 0.04


def range_without_start(ax: Axes, series: Sequence[tuple[np.ndarray, np.ndarray]], headroom: float = 0.0) -> str:
    """Set ax's y range from the samples at t >= RANGE_FROM, with ``headroom`` x the range free above
    them; return a note on what is off scale."""
    inside = [np.asarray(v, dtype=float)[np.asarray(t) >= RANGE_FROM] for t, v in series]
    inside = [v[np.isfinite(v)] for v in inside]
    values = np.concatenate(inside) if inside else np.array([])
    if values.size == 0:
        return ""
    low, high = float(values.min()), float(values.max())
    pad = 0.08 * (high - low) if high > low else max(abs(high), 1e-12) * 0.1
    ax.set_ylim(low - pad, high + pad + headroom * (high - low + 2 * pad))
    outside = [float(np.nanmax(np.abs(np.asarray(v, dtype=float)[np.asarray(t) < RANGE_FROM])))
               for t, v in series if np.any(np.asarray(t) < RANGE_FROM)]
    peak = max(outside, default=0.0)
    if peak > max(abs(low), abs(high)) + pad:
        return f"off scale before t = {RANGE_FROM * 1e3:.0f} ms:\n|value| up to {peak:.3g}"
    return ""


def free_top(ax: Axes, fraction: float) -> None:
    """Raise the top of ax's y range so that the upper ``fraction`` of the axes holds no data (on a
    log axis, in decades)."""
    low, high = ax.get_ylim()
    if ax.get_yscale() == "log" and low > 0 and high > low:
        span = math.log10(high) - math.log10(low)
        ax.set_ylim(low, 10 ** (math.log10(low) + span / (1.0 - fraction)))
    elif high > low:
        ax.set_ylim(low, low + (high - low) / (1.0 - fraction))


@contextlib.contextmanager
def report_style() -> Iterator[None]:
    """Context in which figures are created and saved with ``style.mplstyle``."""
    style = resources.files("ilcforce.report").joinpath("style.mplstyle")
    with resources.as_file(style) as path, matplotlib.style.context(str(path)):
        yield
