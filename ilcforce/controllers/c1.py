"""C1: traditional sliding mode control with a nominal model (eq. 26, docs/model.md#c1).

tau_j = J^T (k sigma_j + alpha sgn(sigma_j) + Xi_nom^T Psi_j + w F_j), with
Xi_nom^T Psi_j = D_nom psi1 + C_nom (dP + sigma) + G_nom (eqs. 11-12), D_nom, C_nom and G_nom the
nominal task-space model at the measured state (G_nom = 0 for the five-bar). Memoryless: nothing is learned between iterations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.controllers.base import (
    DIAG_SIGMA, GAIN_FEEDFORWARD_SIGN, MEAS_FORCE, MEAS_TASK_CORIOLIS, MEAS_TASK_GRAVITY,
    MEAS_TASK_INERTIA, MemoryController, check_vector, compiled_law, gain_indices, joint_torque,
    pack_gains, sgn, surface_terms,
)
from ilcforce.controllers.nd import (
    D_SIGMA, D_U, G_FEEDFORWARD_SIGN, M_FORCE, at, check_widths, compiled_law_nd, gain_offsets, joint_torque_nd,
    nominal_model_force_nd, surface_nd,
)


@dataclass(frozen=True)
class C1Gains:
    """Gains of eq. (26)."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "alpha": "N"}

    k: tuple[float, ...] = (10.0, 100.0)  # diagonal of k, N s/m
    alpha: float = 0.1  # switching gain, N (must exceed |F_v|)

    def __post_init__(self) -> None:
        check_widths("c1", self)  # k: one entry per task axis
        check_vector("c1.k", self.k, len(self.k))
        if not (np.isfinite(self.alpha) and self.alpha >= 0):
            raise ValueError(f"c1.alpha must be finite and >= 0, got {self.alpha!r}")


K, ALPHA = gain_indices(C1Gains, "k", "alpha")
K_ND, ALPHA_ND = gain_offsets(C1Gains, "k", "alpha")


@njit(cache=True, error_model="numpy")
def nominal_model_force(meas, p1x, p1y, p2x, p2y):
    """Xi_nom^T Psi = D_nom psi1 + C_nom (dP + sigma) + G_nom, the nominal model's task force (N), per axis."""
    D00 = meas[MEAS_TASK_INERTIA]
    D01 = meas[MEAS_TASK_INERTIA + 1]
    D11 = meas[MEAS_TASK_INERTIA + 2]
    C00 = meas[MEAS_TASK_CORIOLIS]
    C01 = meas[MEAS_TASK_CORIOLIS + 1]
    C10 = meas[MEAS_TASK_CORIOLIS + 2]
    C11 = meas[MEAS_TASK_CORIOLIS + 3]
    # Xi_nom^T Psi = D psi1 + C (dP + sigma) + G                                  eqs. (11)-(12)
    mx = D00 * p1x + D01 * p1y + C00 * p2x + C01 * p2y + meas[MEAS_TASK_GRAVITY]
    my = D01 * p1x + D11 * p1y + C10 * p2x + C11 * p2y + meas[MEAS_TASK_GRAVITY + 1]
    return mx, my


def c1_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    sx, sy, p1x, p1y, p2x, p2y = surface_terms(k, meas, ref, gains, False)
    w = gains[GAIN_FEEDFORWARD_SIGN]
    mx, my = nominal_model_force(meas, p1x, p1y, p2x, p2y)
    alpha = gains[ALPHA]
    # eq. (26), with +w F (erratum 1)
    ux = gains[K] * sx + alpha * sgn(sx) + mx + w * meas[MEAS_FORCE]
    uy = gains[K + 1] * sy + alpha * sgn(sy) + my + w * meas[MEAS_FORCE + 1]
    diag[DIAG_SIGMA] = sx
    diag[DIAG_SIGMA + 1] = sy
    return joint_torque(meas, ux, uy)


def c1_law_nd(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """eq. (26) on n task axes (docs/model.md#n-dof), C1's arithmetic axis by axis."""
    n = tau.shape[0]
    surface_nd(n, k, meas, ref, gains, False, diag)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    alpha = gains[at(ALPHA_ND, n)]
    for i in range(n):
        sigma = diag[D_SIGMA[0] + i]
        m = nominal_model_force_nd(n, meas, diag, i)
        # eq. (26), with +w F (erratum 1)
        diag[at(D_U, n) + i] = gains[at(K_ND, n) + i] * sigma + alpha * sgn(sigma) + m + w * meas[at(M_FORCE, n) + i]
    joint_torque_nd(n, meas, diag, at(D_U, n), tau)
    return 0


class C1Controller(MemoryController):
    name = "c1"
    law = compiled_law(c1_law)
    law_nd = compiled_law_nd(c1_law_nd)
    uses_nominal_dynamics = True
    memory_layout = {}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: C1Gains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        # the nominal G arrives in meas (MEAS_TASK_GRAVITY, zero without gravity): nothing to switch
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
