"""One seed's readings for the paper's claims (:mod:`ilcforce.report.claim_parts`): the converged windows before
and after the plant's change, norms and chattering at an iteration, the configuration's numbers, and the stop
that ends one part's evaluation in one seed (a failure, or not evaluable), all in one place so that every part
reads a seed the same way.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ilcforce.report import paper
from ilcforce.report.seedframes import SeedMetrics

#: Claims 1 and 2 read converged windows of this many iterations: before the perturbation the last
#: ones before it (j = p-5..p-1, 5..9 in the paper, the window j̄'s definition calls settled), after
#: it the ones from p + RELEARN on (j = 15..19). Why: the claims are about tracking after learning
#: ("after convergence"); a mean that includes j = 1, 2, or a value at j̄ (a number ilcforce defines,
#: which the paper does not), compares iterations still learning.
CONVERGED_WINDOW = 5
#: Claim 2's window after the perturbation starts this many iterations after it (re-learning time:
#: the paper's C2 and C3 converge within 2-4 iterations, Table 2).
RELEARN = 5

class Stop(Exception):
    """Ends one part's evaluation in one seed: ``passed`` False (a failure) or None (not evaluable).
    ``diverged``: the failure is a divergence of the method the part praises (claims.py counts those
    seeds: a part whose method diverged in most seeds is not evaluable, with the divergence named)."""

    def __init__(self, passed: bool | None, note: str, diverged: bool = False) -> None:
        super().__init__(note)
        self.passed, self.note, self.diverged = passed, note, diverged


def norm_ratio(numerator: float, denominator: float) -> float:
    """numerator / denominator for norms >= 0: x / 0 is inf (0 / 0 is NaN), x / inf is 0."""
    numerator, denominator = float(numerator), float(denominator)
    if denominator == 0.0:
        return math.nan if numerator == 0.0 else math.inf
    return numerator / denominator


class Seed:
    """One seed's per-method metrics (:class:`~ilcforce.report.seedframes.SeedMetrics`) plus the checks parts share."""

    def __init__(self, metrics_by_method: Mapping[str, SeedMetrics], p: int, config: Mapping | None = None) -> None:
        self.metrics, self.p = metrics_by_method, int(p)
        self.config = config if isinstance(config, Mapping) else {}

    def setting(self, section: str, key: str) -> float:
        """A number of the setting's resolved configuration; not evaluable when it is not there."""
        value = self.config.get(section, {}).get(key) if isinstance(self.config.get(section), Mapping) else None
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise Stop(None, f"the configuration holds no {section}.{key}")
        return float(value)

    def need(self, *methods: str) -> None:
        missing = [m for m in methods if m not in self.metrics]
        if missing:
            raise Stop(None, "no results for " + ", ".join(missing))

    def asserted(self, method: str, last: int) -> None:
        """A method the part praises diverged at or before ``last``: the part fails."""
        self.need(method)
        found = self.metrics[method].divergence
        if found is not None and found[0] <= last:
            raise Stop(False, f"{method} diverged at iteration {found[0]}", diverged=True)

    def norm(self, method: str, column: str, j: int) -> float:
        """The norm at ``j``; inf from a divergence on (a baseline lost tracking); missing -> not evaluable."""
        self.need(method)
        found = self.metrics[method].divergence
        if found is not None and j >= found[0]:
            return math.inf
        value = self.metrics[method].value_at(column, j)
        if not math.isfinite(value):
            raise Stop(None, f"{method} has no complete iteration {j}")
        return value

    def mean_norm(self, method: str, column: str, first: int, last: int) -> float:
        return float(np.mean([self.norm(method, column, j) for j in range(first, last + 1)]))

    def noise_scale(self) -> float:
        """noise.scale of the configuration; 1 where it predates the key (every source at its own level)."""
        noise = self.config.get("noise")
        value = noise.get("scale", 1.0) if isinstance(noise, Mapping) else 1.0
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else 1.0

    def setting_factor(self) -> float:
        """The perturbation's factor (true / nominal), from the configuration."""
        perturbation = self.config.get("plant", {}).get("perturbation", {}) if isinstance(
            self.config.get("plant"), Mapping) else {}
        value = perturbation.get("factor") if isinstance(perturbation, Mapping) else None
        if not isinstance(value, (int, float)):
            raise Stop(None, "the configuration holds no plant.perturbation.factor")
        return float(value)

    def before_last(self) -> int:
        """The last iteration :meth:`before_window` may read (an asserted method must reach it)."""
        return self.p - 1 if self.p > 1 else self.p + RELEARN + CONVERGED_WINDOW - 1

    def before_window(self, methods: tuple[str, ...]) -> tuple[int, int]:
        """The converged window before the perturbation: its last CONVERGED_WINDOW iterations
        (j = 5..9 in the paper's setup), never j = 0. A plant changed from j = 0 or 1 on (a
        nominal-model error from the start) leaves no iteration before it: the window is then
        the converged one under the one changed plant, j = p+RELEARN.. (5..9 for p = 0)."""
        if self.p <= 1:
            return self.after_window(methods)
        last = self.p - 1
        return max(1, last - CONVERGED_WINDOW + 1), last

    def after_window(self, methods: tuple[str, ...]) -> tuple[int, int]:
        """The converged window after the perturbation: j = p + RELEARN .. p + RELEARN +
        CONVERGED_WINDOW - 1 (15..19), ended at the last iteration all ``methods`` completed."""
        self.need(*methods)
        first = self.p + RELEARN
        ends = [max(self.metrics[m].complete_iterations, default=-1) for m in methods]
        last = min(first + CONVERGED_WINDOW - 1, *ends)
        if last < first:
            raise Stop(None, f"needs iterations up to at least {first}; the runs stop at {min(ends)}")
        return first, last

    def jbar(self, method: str, column: str) -> int:
        self.asserted(method, 9)
        found = self.metrics[method].jbar(column)
        if found is None:
            raise Stop(None, f"{method}: j̄ needs complete iterations 0..9")
        return found

    def chattering_before(self, method: str, column: str) -> float:
        """H at j = p - 1, the last iteration before the perturbation (finite, or not evaluable)."""
        j = self.p - 1
        if j < 0:
            raise Stop(None, f"perturbation at {self.p} leaves no iteration before it")
        self.need(method)
        found = self.metrics[method].divergence
        if found is not None and found[0] <= j:
            raise Stop(None, f"{method} diverged at iteration {found[0]}")
        value = self.metrics[method].value_at(column, j)
        if not math.isfinite(value):
            raise Stop(None, f"{method} has no complete iteration {j}")
        return value

    def chattering_at(self, method: str, column: str, j: int) -> float:
        """H at iteration ``j`` (finite, or not evaluable); C3, the method claim 5 praises, fails where it
        diverged by ``j``."""
        self.asserted(method, j) if method == "c3" else self.need(method)
        value = self.metrics[method].value_at(column, j)
        if not math.isfinite(value):
            raise Stop(None, f"{method} has no complete iteration {j}")
        return value

    def last_common(self, methods: tuple[str, ...]) -> int:
        """The last iteration every one of ``methods`` completed (-1 when one completed none)."""
        self.need(*methods)
        return min(max(self.metrics[m].complete_iterations, default=-1) for m in methods)

    def reading_iteration(self, at: str) -> int:
        """The iteration another reading of claim 5 reads (:data:`READINGS`): ``"before"`` j = p - 1, the
        last before the plant changes; ``"last"`` the last iteration C1 and C3 both completed. Not
        evaluable where that is the judged iteration itself, or (``"last"``) not after it."""
        j = self.p - 1 if at == "before" else self.last_common(("c1", "c3"))
        if j < 0 or j == paper.CHATTERING_ITERATION or (at == "last" and j < paper.CHATTERING_ITERATION):
            raise Stop(None, f"no other iteration to read ({at})")
        return j

    def chattering(self, method: str, column: str) -> float:
        self.asserted(method, paper.CHATTERING_ITERATION) if method == "c3" else self.need(method)
        j = self.metrics[method].chattering_iteration()
        if j != paper.CHATTERING_ITERATION:
            raise Stop(None, f"{method} has no complete iteration {paper.CHATTERING_ITERATION}")
        value = self.metrics[method].value_at(column, j)
        if not math.isfinite(value):
            raise Stop(None, f"{column} not available for {method}")
        return value
