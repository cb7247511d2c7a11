"""SL-adapt: Slotine-Li adaptive sliding control of the same D, C parameters, without iteration memory.

Why this method: C3 combines two things, a sliding-mode structure with a regressor Phi^T Theta
(D psi1 + C (dP + sigma), eqs. 11-13) and *iterative* learning of Theta_hat(t) indexed by time and
carried from trial to trial. A reviewer's first question is which of the two does the work: would
ordinary *adaptation* of the same regressor parameters within one motion, the classic adaptive
robot controller of Slotine & Li ("On the adaptive control of robot manipulators", IJRR 6(3), 1987;
Applied Nonlinear Control, 1991, sec. 9.2, eqs. 9.25-9.27), do as well? This method is that
controller, on C3's own regressor and surface, with the learning across iterations removed:

tau(t)             = J^T (k sigma(t) + Phi(t)^T Theta_hat(t) + w F(t))         (Slotine & Li eq. 9.25)
dTheta_hat/dt      = Gamma_a Phi(t) sigma(t)                                  (Slotine & Li eq. 9.27)
Theta_hat(t_k)     = Theta_hat(t_{k-1}) + Ts Gamma_a Phi(t_k) sigma(t_k),  Theta_hat(t_{-1}) = 0

With a plant that has gravity the regressor gains C3's G block (Psi = [psi1; dP + sigma; 1 1], 12
entries), as C3's does. (Backward Euler on the control grid, so that Phi^T Theta_hat holds the same Phi^T Gamma Phi sigma
term as eq. (14) and the law stays quadratic in the acceleration.) Every iteration starts again from
Theta_hat = 0, as C3's first iteration does: the adaptation is the only learning, so any gain of C3
over this method across iterations is due to iteration memory. No switching term: Slotine & Li's
adaptive law has none (C3's alpha_hat is itself learned across iterations).

The memory stored per iteration is the Theta_hat(t) trajectory the iteration adapted (for
inspection); it does not seed the next iteration (``MethodSpec.carries_memory`` is False).

Default gains, from a stated rule (not tuned against C3): k = C3's; Gamma_a = Gamma_C3 / T with the
paper's trial length T = 2 s, "equal learning authority per trial": over one trial, a constant
Phi sigma moves Theta_hat by as much as one C3 iteration moves Theta_hat_j(t).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce._jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/_jit.py)
from ilcforce.controllers.base import (
    DIAG_SIGMA, GAIN_FEEDFORWARD_SIGN, MEAS_FORCE, MemoryController, check_vector, compiled_law,
    gain_indices, joint_torque, pack_gains, surface_terms,
)


@dataclass(frozen=True)
class SlotineLiGains:
    """Gains of the adaptive sliding controller (Slotine & Li 1991, eqs. 9.25-9.27)."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "gamma": "mixed: kg s^2/m^2 (D entries), kg/m^2 (C entries)",
                                       "gamma_gravity": "N/m"}

    k: tuple[float, float] = (10.0, 100.0)  # feedback gain diagonal, N s/m (C3's)
    gamma: tuple[float, ...] = (2e3, 20.0, 5e3, 5e3, 500.0, 500.0, 5e3, 5e3)  # Gamma_a diagonal, 1/s (Gamma_C3 / 2 s)
    # Gamma_a of the G block (G11 G12 G21 G22), only with a plant that has gravity: C3's / 2 s
    gamma_gravity: tuple[float, float, float, float] = (500.0, 500.0, 500.0, 500.0)

    def __post_init__(self) -> None:
        check_vector("sl-adapt.k", self.k, 2)
        check_vector("sl-adapt.gamma", self.gamma, 8)
        check_vector("sl-adapt.gamma_gravity", self.gamma_gravity, 4)
        if min(self.gamma) < 0 or min(self.gamma_gravity) < 0:
            raise ValueError("sl-adapt.gamma and gamma_gravity must be non-negative (Gamma_a is positive semi-definite)")


K, GAMMA, GAMMA_GRAVITY, SAMPLE_TIME = gain_indices(SlotineLiGains, "k", "gamma", "gamma_gravity", "sample_time",
                                                    derived=("sample_time",))


@njit(cache=True, error_model="numpy")
def _gamma_entry(gains, axis, r):
    """Gamma_a's entry for Theta row r of task axis ``axis`` (rows 4-5: the G block), as C3's."""
    if r < 4:
        return gains[GAMMA + 4 * axis + r]
    return gains[GAMMA_GRAVITY + 2 * axis + r - 4]


def sl_adapt_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    sx, sy, p1x, p1y, p2x, p2y = surface_terms(k, meas, ref, gains, False)  # eqs. (8), (12)
    w = gains[GAIN_FEEDFORWARD_SIGN]
    ts = gains[SAMPLE_TIME]
    na = mem_new.shape[1] // 2  # Psi's length: 4 (G = 0) or 6 (with the G block), as C3
    mx = 0.0  # (Phi^T Theta_hat)_x
    my = 0.0
    for r in range(na):
        psi = p1x if r == 0 else (p1y if r == 1 else (p2x if r == 2 else (p2y if r == 3 else 1.0)))  # eq. (12)
        # Theta_hat(t_{k-1}): this iteration's previous sample (mem_new row k - 1), 0 at k = 0
        prev_x = mem_new[k - 1, r] if k > 0 else 0.0
        prev_y = mem_new[k - 1, na + r] if k > 0 else 0.0
        th_x = prev_x + ts * _gamma_entry(gains, 0, r) * psi * sx  # Slotine & Li eq. 9.27, backward Euler
        th_y = prev_y + ts * _gamma_entry(gains, 1, r) * psi * sy
        mx += th_x * psi
        my += th_y * psi
        if write:
            mem_new[k, r] = th_x
            mem_new[k, na + r] = th_y
    # Slotine & Li eq. 9.25 in task space, with +w F (erratum 1)
    ux = gains[K] * sx + mx + w * meas[MEAS_FORCE]
    uy = gains[K + 1] * sy + my + w * meas[MEAS_FORCE + 1]
    diag[DIAG_SIGMA] = sx
    diag[DIAG_SIGMA + 1] = sy
    return joint_torque(meas, ux, uy)


class SlotineLiController(MemoryController):
    name = "sl-adapt"
    law = compiled_law(sl_adapt_law)
    uses_nominal_dynamics = False
    memory_layout = {"theta_hat": (0, 8, "mixed: kg (D entries), kg/s (C entries)")}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: SlotineLiGains, *,
                 gravity: bool = False, sample_time: float = float("nan")):
        if gravity:  # C3's full regressor (eq. 13) with the G block
            self.memory_layout = {"theta_hat": (0, 12, "mixed: kg (D entries), kg/s (C entries), N (G entries)")}
        super().__init__(n_control, sample_time)
        if not (np.isfinite(self.sample_time) and self.sample_time > 0):
            raise ValueError("sl-adapt needs the control sample time to integrate its adaptation")
        self._gains = pack_gains(surface, wall_sign, gains, derived={"sample_time": self.sample_time})

    def gains(self) -> np.ndarray:
        return self._gains
