"""SMC-BL: C1 with a boundary layer, the textbook cure for chattering (Slotine & Li 1991, sec. 7.2).

C1 (eq. 26) switches with sgn(sigma); with noisy measurements sigma crosses zero at every sample and
the switching term alpha sgn(sigma) chatters at the sample rate. Slotine & Li (Applied Nonlinear
Control, 1991, sec. 7.2, eqs. 7.30-7.31) replace sgn by sat(sigma / phi) inside a boundary layer of
thickness phi: outside it the law is C1's, inside it the switching term is a linear gain alpha / phi.

tau_j = J^T (k sigma_j + alpha sat(sigma_j / phi) + Xi_nom^T Psi_j + w F_j)   (eq. 26 with sgn -> sat)
sat(z) = z for |z| <= 1, sgn(z) otherwise, per axis.

Default gains: k and alpha are C1's (the paper's Section 4.1), so the only difference from C1 is the
boundary layer. Design rule for phi: inside the layer the switching term must not stiffen the loop
beyond the linear feedback it was designed with, i.e. its slope alpha / phi_i equals k_i, which gives
phi_i = alpha / k_i = (0.1 / 10, 0.1 / 100) = (0.01, 0.001) m/s. The tracking error this costs is
bounded by the layer (Slotine & Li: |sigma| <= phi once inside it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.controllers.base import MemoryController, check_vector, pack_gains
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, M_FORCE, at, check_widths, compiled_law, gain_offsets, joint_torque, nominal_model_force,
    surface,
)


@dataclass(frozen=True)
class SMCBoundaryLayerGains:
    """Gains of eq. (26) with a boundary layer."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "alpha": "N", "phi": "m/s"}

    k: tuple[float, ...] = (10.0, 100.0)  # diagonal of k, N s/m (C1's)
    alpha: float = 0.1  # switching gain, N (C1's)
    phi: tuple[float, ...] = (0.01, 0.001)  # boundary-layer thickness per axis, m/s (alpha / k)

    def __post_init__(self) -> None:
        n = check_widths("smc-bl", self)  # k and phi: one entry per task axis
        check_vector("smc-bl.k", self.k, n)
        check_vector("smc-bl.phi", self.phi, n)
        if not (np.isfinite(self.alpha) and self.alpha >= 0):
            raise ValueError(f"smc-bl.alpha must be finite and >= 0, got {self.alpha!r}")
        if min(self.phi) <= 0:
            raise ValueError(f"smc-bl.phi must be positive (phi -> 0 is C1), got {self.phi!r}")


K, ALPHA, PHI = gain_offsets(SMCBoundaryLayerGains, "k", "alpha", "phi")


@njit(cache=True, error_model="numpy")
def sat(z):
    """Saturation: z inside [-1, 1], its sign outside (Slotine & Li 1991, eq. 7.31)."""
    if z > 1.0:
        return 1.0
    if z < -1.0:
        return -1.0
    return z


def smc_bl_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """Eq. (26) with sgn -> sat on the task's n axes, axis by axis."""
    n = tau.shape[0]
    surface(n, k, meas, ref, gains, False, diag)  # eqs. (8), (12)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    alpha = gains[at(ALPHA, n)]
    for i in range(n):
        sigma = diag[i]
        m = nominal_model_force(n, meas, diag, i)  # Xi_nom^T Psi, eqs. (11)-(12)
        # eq. (26) with sgn(sigma) -> sat(sigma / phi) (Slotine & Li 1991, eq. 7.30), +w F (erratum 1)
        diag[at(D_U, n) + i] = (gains[at(K, n) + i] * sigma + alpha * sat(sigma / gains[at(PHI, n) + i]) + m
                                + w * meas[at(M_FORCE, n) + i])
    joint_torque(n, meas, diag, at(D_U, n), tau)
    return 0


class SMCBoundaryLayerController(MemoryController):
    name = "smc-bl"
    law = compiled_law(smc_bl_law)
    uses_nominal_dynamics = True
    memory_layout = {}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: SMCBoundaryLayerGains, *,
                 gravity: bool = False, sample_time: float = float("nan")):
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
