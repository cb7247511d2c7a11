"""C2-robust: the traditional ILC of eq. (27) made to stay bounded over long runs (docs/model.md#long-run).

Under the paper's setup C2's learned torque grows without bound: at the first samples linearly (the same
start mismatch every iteration) and over the trajectory geometrically (the noise it integrates), so its
chattering grows about 3% per iteration. C2-robust is eq. (27) with the two tools of
``ilcforce.controllers.robust`` aimed at those two causes:

sigma_L(t) = sigma(t) for t >= t_L, 0 before                            (learning window)
v_j(t)     = v_{j-1}(t) + J_j^T k sigma_L(t)                              (eq. 27, learning update)
tau_j      = v_j + J^T k (sigma_j - sigma_L) + w J^T F_j                  (eq. 27 + the feedback the update skips)
after iteration j: v_j <- Q v_j                                           (zero-phase Q filter)

In eq. (27) the current-iteration update J^T k sigma_j is also the law's only feedback. Where the window
withholds sigma from the memory, the same J^T k sigma still acts as feedback in this iteration (the middle
term), so C2-robust's feedback is C2's everywhere; only what is remembered differs.

Default options: C3-robust's learning window (5 ms) and Q filter (50 Hz), chosen the same way
(``ilcforce.controllers.c3_robust``); on the tuning seed C2-robust's force error over j = 15..19 was
1.78 N against plain C2's 1.62 N, its position error equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ilcforce.controllers.c2 import GRAVITY_FEEDFORWARD, K, C2Controller, C2Gains, c2_torque
from ilcforce.controllers.nd import at, compiled_law, gain_offsets
from ilcforce.controllers.robust import QFiltered, check_robust_gains


@dataclass(frozen=True)
class C2RobustGains(C2Gains):
    """C2's gains (eq. 27) plus the learning window and the Q filter."""

    section: ClassVar[str] = "c2-robust"
    units: ClassVar[dict[str, str]] = {**C2Gains.units, "learn_from": "s", "q_cutoff": "Hz", "q_order": "1"}
    learn_from: float = 0.005  # t_L: no learning before this time in each iteration, s
    q_cutoff: float = 50.0  # Q filter cutoff, Hz (0: no filter)
    q_order: int = 2  # Butterworth order of Q (run forwards and backwards)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_robust_gains(self.section, self.learn_from, self.q_cutoff, self.q_order)


*_SHARED, LEARN_FROM, _Q_CUTOFF, _Q_ORDER = gain_offsets(
    C2RobustGains, "k", "gravity_feedforward", "learn_from", "q_cutoff", "q_order")
assert tuple(_SHARED) == (K, GRAVITY_FEEDFORWARD), "C2-robust packs C2's gains at C2's offsets (the shared kernel reads them)"


def c2_robust_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    # eq. (27) learning only from t_L on; before it J^T k sigma feeds back (Q runs after the iteration)
    n = tau.shape[0]
    return c2_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, t >= gains[at(LEARN_FROM, n)])


class C2RobustController(QFiltered, C2Controller):
    """C2's controller (memory layout, gain packing) with the robust law and Q on the memory."""

    name = "c2-robust"
    law = compiled_law(c2_robust_law)
