"""A judged part's passing range: its margin, and what the 95% interval of its median says.

A judged part of a claim (:mod:`ilcforce.report.claim_parts`) passes in a seed when its statistic lies
in a range: below an edge (``< 1``, ``<= 5``), above one (``>= 2``, ``> 1``) or between two ("within
x1.1 of 1.67"). :class:`PassRange` holds that range once, so that three things read the same edges:

* the **margin** of a value (calling the range): its signed distance to the nearest edge as a
  fraction of that edge, >= 0 on the passing side (docs/tables.md, "Terms");
* whether a value passes (:meth:`PassRange.contains`, with the part's own strictness at an edge);
* what the 95% bootstrap interval of the median over seeds says (:func:`interval_outcomes`): the
  outcomes ("pass", "partly", "fail") a median anywhere in that interval would give. More than one
  means the interval crosses a threshold: the part's verdict is then "uncertain" (claims.py, rule 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: A value's outcome against a part's range: passes, fails the threshold but meets the part's weaker
#: reading (claim 2: C3 below C2 at all), or fails.
PASS, PARTLY, FAIL = "pass", "partly", "fail"


@dataclass(frozen=True)
class PassRange:
    """The passing range ``low`` .. ``high`` of a statistic (an open side is infinite).

    ``strict``: the edges themselves fail (the part's test is ``<`` or ``>``); else they pass
    (``<=``, ``>=``, "within"). Calling the range gives a value's margin: the smaller of
    (high - x) / high and (x - low) / low over the finite edges."""

    low: float = -math.inf
    high: float = math.inf
    strict: bool = False

    def __call__(self, x: float) -> float:
        margins = []
        if math.isfinite(self.high):
            margins.append((self.high - x) / self.high)
        if math.isfinite(self.low):
            margins.append((x - self.low) / self.low)
        return min(margins)

    def contains(self, x: float) -> bool:
        """Whether ``x`` passes (NaN never does)."""
        if self.strict:
            return bool(self.low < x < self.high)
        return bool(self.low <= x <= self.high)

    @property
    def edges(self) -> tuple[float, ...]:
        """The finite edges, where a value's outcome can change."""
        return tuple(e for e in (self.low, self.high) if math.isfinite(e))


def below(threshold: float, strict: bool = False) -> PassRange:
    """A statistic that must stay below ``threshold`` (the edge): margin (threshold - x) / threshold.
    ``strict``: the test is ``<`` (the edge fails), else ``<=``."""
    return PassRange(high=threshold, strict=strict)


def above(threshold: float, strict: bool = False) -> PassRange:
    """A statistic that must reach ``threshold`` (the edge): margin (x - threshold) / threshold.
    ``strict``: the test is ``>``, else ``>=``."""
    return PassRange(low=threshold, strict=strict)


def within(published: float, factor: float) -> PassRange:
    """A ratio that must lie within ``factor`` of ``published`` either way, i.e. in
    [published / factor, published x factor]: the margin is the distance to the nearer edge as a fraction
    of it, the smaller of :func:`below` (published x factor) and :func:`above` (published / factor).
    6.25 against 1.67 x 1.1 = 1.837 is -240%."""
    return PassRange(low=published / factor, high=published * factor)


def outcome(x: float, passing: PassRange, partly: PassRange | None = None) -> str:
    """:data:`PASS`, :data:`PARTLY` (fails ``passing``, meets the weaker ``partly``) or :data:`FAIL`."""
    if passing.contains(x):
        return PASS
    return PARTLY if partly is not None and partly.contains(x) else FAIL


def interval_outcomes(low: float, high: float, passing: PassRange,
                      partly: PassRange | None = None) -> frozenset[str]:
    """The outcomes a median anywhere in [``low``, ``high``] would give (the median's 95% interval).

    One outcome: the interval lies clear of every threshold. Several: it crosses one, and the verdict
    is uncertain between them. Empty when the interval has no finite end (no finite value over seeds).
    Exact, because an outcome changes only at an edge: the ends and every edge inside the interval
    give every outcome it holds."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return frozenset()
    edges = passing.edges + (partly.edges if partly is not None else ())
    points = [low, high] + [e for e in edges if low <= e <= high]
    return frozenset(outcome(x, passing, partly) for x in points)
