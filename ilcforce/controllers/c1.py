"""C1: traditional sliding mode control with a nominal model (eq. 26, docs/model.md#c1).

tau_j = J^T (k sigma_j + alpha sgn(sigma_j) + Xi_nom^T Psi_j + w F_j), with
Xi_nom^T Psi_j = D_nom psi1 + C_nom (dP + sigma) + G_nom (eqs. 11-12), D_nom, C_nom and G_nom the
nominal task-space model at the measured state (G_nom = 0 for the five-bar). Memoryless: nothing is learned between iterations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.controllers.base import MemoryController, check_vector, pack_gains, sgn
from ilcforce.controllers.nd import (
    D_SIGMA, D_U, G_FEEDFORWARD_SIGN, M_FORCE, at, check_widths, compiled_law, gain_offsets, joint_torque,
    nominal_model_force, surface,
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


K, ALPHA = gain_offsets(C1Gains, "k", "alpha")


def c1_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """eq. (26) on the task's n axes, axis by axis."""
    n = tau.shape[0]
    surface(n, k, meas, ref, gains, False, diag)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    alpha = gains[at(ALPHA, n)]
    for i in range(n):
        sigma = diag[D_SIGMA[0] + i]
        m = nominal_model_force(n, meas, diag, i)
        # eq. (26), with +w F (erratum 1)
        diag[at(D_U, n) + i] = gains[at(K, n) + i] * sigma + alpha * sgn(sigma) + m + w * meas[at(M_FORCE, n) + i]
    joint_torque(n, meas, diag, at(D_U, n), tau)
    return 0


class C1Controller(MemoryController):
    name = "c1"
    law = compiled_law(c1_law)
    uses_nominal_dynamics = True
    memory_layout = {}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: C1Gains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        # the nominal G arrives in meas (M_TASK_GRAVITY, zero without gravity): nothing to switch
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
