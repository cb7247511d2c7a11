"""C3-leak: the paper's C3 (eq. 14) with leakage and a bound on the switching gain.

Without a forgetting factor, C3 integrates every iteration's noise and non-repetitive disturbance
into Theta_hat and alpha_hat for ever; the ``long-run`` experiment shows the result (growing
chattering, divergence). The textbook remedy for such parameter drift is leakage, the
sigma-modification of adaptive control (Ioannou & Kokotovic 1983; Ioannou & Sun, Robust Adaptive
Control, 1996, sec. 8.5.2), which in ILC is the forgetting factor of Arimoto (1990) and Heinzinger
et al. (IEEE TAC 37(1), 1992), plus a projection that keeps the switching gain bounded:

Theta_hat_j(t) = (1 - lambda) Theta_hat_{j-1}(t) + Gamma Phi_j(t) sigma_j(t)          (eq. 14 + leakage)
alpha_hat_j(t) = min(alpha_max, (1 - lambda) alpha_hat_{j-1}(t) + eta sigma_j^T sgn(sigma_j))
tau_j          = J^T (k sigma_j + Phi_j^T Theta_hat_j + w F_j + alpha_hat_j sgn(sigma_j))  (eq. 14)

With lambda = 0 and alpha_max = inf this is C3 exactly (same kernel, ``c3.c3_torque``). The price
of leakage is a bias: an unbiased steady state needs lambda Theta = Gamma Phi sigma, so the
error no longer goes to zero in the noise-free limit.

Default gains, from stated rules (not tuned against C3):
* k, eta, Gamma, psi_acceleration: C3's (the paper's Section 4.1), so only the two additions differ;
* leakage lambda = 0.02 per iteration: a memory horizon 1 / lambda = 50 iterations, 2.5x the paper's
  20-iteration experiment, so learning within the paper's run is mostly kept ((1 - lambda)^20 = 0.67
  of a contribution survives) while what noise adds is forgotten over a long run;
* alpha_max = 0.1 N: the fixed switching gain the paper itself deems sufficient for C1 (Section
  4.1; 5x the 0.02 N disturbance bound of docs/model.md#noise), so the learned gain may reach, but not
  exceed, what a robust switching term needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from ilcforce.controllers.c3 import (
    ETA, GAMMA, GAMMA_GRAVITY, GRAVITY_FEEDFORWARD, K, PSI_ACCELERATION_FLAG, C3Controller, C3Gains, c3_torque,
)
from ilcforce.controllers.nd import at, compiled_law, gain_offsets


@dataclass(frozen=True)
class C3LeakGains(C3Gains):
    """C3's gains (eq. 14) plus the leakage and the switching-gain bound."""

    section: ClassVar[str] = "c3-leak"
    units: ClassVar[dict[str, str]] = {**C3Gains.units, "leakage": "1", "alpha_max": "N"}
    leakage: float = 0.02  # lambda: fraction of the previous iteration's memory forgotten, 0 <= lambda < 1
    alpha_max: float = 0.1  # bound on alpha_hat, N

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.leakage) and 0.0 <= self.leakage < 1.0):
            raise ValueError(f"c3-leak.leakage must be in [0, 1), got {self.leakage!r}")
        if not (self.alpha_max >= 0.0):  # inf allowed: no bound
            raise ValueError(f"c3-leak.alpha_max must be >= 0, got {self.alpha_max!r}")


_C3_OFFSETS = (K, ETA, GAMMA, GAMMA_GRAVITY, PSI_ACCELERATION_FLAG, GRAVITY_FEEDFORWARD)
*_SHARED, LEAKAGE, ALPHA_MAX = gain_offsets(C3LeakGains, "k", "eta", "gamma", "gamma_gravity", "psi_acceleration",
                                            "gravity_feedforward", "leakage", "alpha_max")
assert tuple(_SHARED) == _C3_OFFSETS, "C3-leak packs C3's gains at C3's offsets (the shared kernel reads them)"


def c3_leak_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    # eq. (14) with (1 - lambda) on the previous iteration's memory and alpha_hat <= alpha_max
    n = tau.shape[0]
    return c3_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, 1.0 - gains[at(LEAKAGE, n)],
                     gains[at(ALPHA_MAX, n)], True, 0.0, 0.0)


class C3LeakController(C3Controller):
    """C3's controller (memory layout, gain packing by the gains' own layout) with the leaky law."""

    name = "c3-leak"
    law = compiled_law(c3_leak_law)
