"""C3: the paper's ILC based on the sliding mode technique, eq. (14) (SPEC sections 3 and 4).

tau_j = J^T (k sigma_j + Phi_j^T Theta_hat_j + w F_j + alpha_hat_j sgn(sigma_j))
Theta_hat_j(t) = Theta_hat_{j-1}(t) + Gamma Phi_j(t) sigma_j(t),    Theta_hat_{-1} = 0
alpha_hat_j(t) = alpha_hat_{j-1}(t) + eta sigma_j(t)^T sgn(sigma_j(t)),  alpha_hat_{-1} = 0

With G = 0 (erratum 3): Psi = [psi1; dP + sigma] in R^4, Phi = blockdiag(Psi, Psi) in R^(8x2),
Theta = [D11 D12 C11 C12 D21 D22 C21 C22], so Phi^T Theta = D psi1 + C (dP + sigma).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ilcforce.controllers.base import (
    DIAG_SIGMA, GAIN_FEEDFORWARD_SIGN, MEAS_FORCE, MemoryController, check_vector, compiled_law,
    gain_indices, joint_torque, pack_gains, sgn, surface_terms,
)

PSI_ACCELERATION = {"measured": 0.0, "desired": 1.0}


@dataclass(frozen=True)
class C3Gains:
    """Gains of eq. (14) (Section 4.1)."""

    k: tuple[float, float] = (10.0, 100.0)  # feedback gain diagonal, N s/m
    eta: float = 5.0  # learning rate of the switching gain
    gamma: tuple[float, ...] = (4e3, 40.0, 1e4, 1e4, 1e3, 1e3, 1e4, 1e4)  # Gamma diagonal, Theta order
    psi_acceleration: str = "measured"  # "measured": S ddP in Psi (the paper); "desired": S ddP_d

    def __post_init__(self) -> None:
        check_vector("c3.k", self.k, 2)
        check_vector("c3.gamma", self.gamma, 8)
        if not (np.isfinite(self.eta) and self.eta >= 0):
            raise ValueError(f"c3.eta must be finite and >= 0, got {self.eta!r}")
        if min(self.gamma) < 0:
            raise ValueError("c3.gamma must be non-negative (Gamma is positive semi-definite)")
        if self.psi_acceleration not in PSI_ACCELERATION:
            raise ValueError(f"c3.psi_acceleration must be one of {', '.join(PSI_ACCELERATION)}, "
                             f"got {self.psi_acceleration!r}")


K, ETA, GAMMA, PSI_ACCELERATION_FLAG = gain_indices(C3Gains, "k", "eta", "gamma", "psi_acceleration")


@njit(cache=True, error_model="numpy")
def c3_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, keep, alpha_max):
    """Eq. (14) at sample k, with the previous iteration's memory scaled by ``keep`` and alpha_hat_j
    capped at ``alpha_max``. The paper's C3 is keep = 1, alpha_max = inf (both then exact no-ops);
    C3-leak (``c3_leak``) uses keep = 1 - leakage and a finite bound."""
    psi_desired = gains[PSI_ACCELERATION_FLAG] > 0.5
    sx, sy, p1x, p1y, p2x, p2y = surface_terms(k, meas, ref, gains, psi_desired)
    w = gains[GAIN_FEEDFORWARD_SIGN]
    # Theta_hat_j = Theta_hat_{j-1} + Gamma Phi sigma: rows 0-3 see Psi sigma_x, rows 4-7 Psi sigma_y
    mx = 0.0  # (Phi^T Theta_hat_j)_x
    my = 0.0  # (Phi^T Theta_hat_j)_y
    for r in range(4):
        psi = p1x if r == 0 else (p1y if r == 1 else (p2x if r == 2 else p2y))
        th_x = keep * mem_prev[k, r] + gains[GAMMA + r] * psi * sx  # eq. (14), Theta update
        th_y = keep * mem_prev[k, 4 + r] + gains[GAMMA + 4 + r] * psi * sy
        mx += th_x * psi
        my += th_y * psi
        if write:
            mem_new[k, r] = th_x
            mem_new[k, 4 + r] = th_y
    sgx = sgn(sx)
    sgy = sgn(sy)
    alpha = keep * mem_prev[k, 8] + gains[ETA] * (sx * sgx + sy * sgy)  # eq. (14), alpha update
    if alpha > alpha_max:  # (a NaN stays NaN, so the watchdog still sees a divergence)
        alpha = alpha_max
    if write:
        mem_new[k, 8] = alpha
    # eq. (14), control law with +w F (erratum 1)
    ux = gains[K] * sx + mx + w * meas[MEAS_FORCE] + alpha * sgx
    uy = gains[K + 1] * sy + my + w * meas[MEAS_FORCE + 1] + alpha * sgy
    diag[DIAG_SIGMA] = sx
    diag[DIAG_SIGMA + 1] = sy
    return joint_torque(meas, ux, uy)


def c3_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return c3_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, 1.0, np.inf)


class C3Controller(MemoryController):
    name = "c3"
    law = compiled_law(c3_law)
    uses_nominal_dynamics = False
    memory_layout = {"theta_hat": (0, 8, "mixed: kg (D entries), kg/s (C entries)"), "alpha_hat": (8, 9, "N")}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: C3Gains, sample_time: float = float("nan")):
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains, encode={"psi_acceleration": PSI_ACCELERATION})

    def gains(self) -> np.ndarray:
        return self._gains
