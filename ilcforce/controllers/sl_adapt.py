"""SL-adapt: Slotine-Li adaptive control with the plant's constant physical parameters.

Why this method: C3 combines a sliding-mode structure with a regressor Phi^T Theta and *iterative*
learning of Theta_hat(t), a function of time carried from trial to trial. A reviewer's first
question is whether classic *adaptive* control of the same robot, which estimates the robot's few
constant physical parameters online (Slotine & Li, "On the adaptive control of robot manipulators",
IJRR 6(3), 1987; Applied Nonlinear Control, 1991, sec. 9.2, eqs. 9.25-9.27), does as well.

The robot's dynamics are linear in a vector a of constant base parameters (each plant provides its
regressor and base parameters; the law reaches them through ``ilcforce.plants.adaptive`` by the
plant's code, so it names no robot: 6 for the five-bar, 5 for the 2R arm with its two gravity moments):

    Dq(q) ddq_r + Cq(q, dq) dq_r + G_q(q) = Y(q, dq, dq_r, ddq_r) a

With C3's surface (eq. 8), the task-space reference velocity is dP_r = dP + sigma and its
derivative ddP_r = psi1 (eq. 12's two blocks), so in joint space

    dq_r  = J^-1 dP_r,    ddq_r = J^-1 (ddP_r - dJ dq_r),    s = dq - dq_r = -J^-1 sigma
    tau   = Y a_hat - K_D s + w J^T F,   K_D = J^T k J  (so -K_D s = J^T k sigma)   (Slotine & Li eq. 9.25)
    da_hat/dt = -Gamma Y^T s = Gamma Y^T J^-1 sigma                                  (Slotine & Li eq. 9.27)

integrated by backward Euler on the control grid (a_hat(t_k) = a_hat(t_{k-1}) + Ts Gamma Y_k^T
J^-1 sigma_k, so the law stays quadratic in the acceleration). There is no switching term
(Slotine & Li's adaptive law has none).

Across iterations: a is constant, so what the adaptation learned about it holds in the next trial;
each iteration starts from the estimate the previous one ended with (``MethodSpec.carries_memory``;
after a diverged iteration, from the one before). Iteration 0 starts from ``initial_estimate`` times
the nominal model's base parameters (1: the nominal model, as C1 has it; 0: nothing). Unlike C3's
Theta_hat(t), the estimate is one vector, not a function of time: it cannot learn a disturbance that
repeats every trial, which is what separates adaptation from iterative learning.

The memory stored per iteration is a_hat(t) - a_hat_0, the change of the estimate from where
iteration 0 started (a_hat_0 = ``initial_estimate`` x the nominal base parameters), so that it starts
at zero as every method's memory does; its last row seeds the next iteration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.dense import lu, lu_solve
from ilcforce.controllers.base import MemoryController, check_vector, pack_common_gains
from ilcforce.controllers.c3 import PSI_ACCELERATION
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, G_OWN_FIRST, M_DTHETA, M_FORCE, M_JACOBIAN, M_THETA, add_joint_torque, at, at_py,
    check_widths, compiled_law, surface,
)
from ilcforce.plants import adaptive

#: Gamma's entries on a 2-joint plant: its closed-form regressor's columns (a plant with fewer base parameters
#: leaves the last unused)
REGRESSOR_WIDTH = adaptive.REGRESSOR_WIDTH


@dataclass(frozen=True)
class SlotineLiGains:
    """Gains of the adaptive controller (Slotine & Li 1991, eqs. 9.25-9.27)."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "gamma": "mixed: per base parameter, its unit^2 per (N s)",
                                       "initial_estimate": "1", "psi_acceleration": ""}

    #: fields as wide as the plant says, not the task (ilcforce.controllers.nd.check_widths)
    plant_sized: ClassVar[tuple[str, ...]] = ("gamma",)

    k: tuple[float, ...] = (10.0, 100.0)  # task-space feedback on sigma, N s/m (C3's): K_D = J^T k J
    # Gamma diagonal per base parameter, in the plant's order (five-bar: M11 M22 M33 M44 k3 k4; 2R arm:
    # a b d g1 g2, the sixth unused; an n-joint arm: one per base parameter, the controller's
    # base_parameter_names). Default: 0.3 for every entry, the middle of the range (0.1-1) that,
    # on the paper's five-bar (seed 0), recovered from m3 x 1.4 within 2-6 iterations and did not drift
    # over 20; chosen on SL-adapt's own errors, not against C3's. The 2R arm's experiment sets its own.
    gamma: tuple[float, ...] = (0.3, 0.3, 0.3, 0.3, 0.3, 0.3)
    initial_estimate: float = 1.0  # a_hat at j = 0 as a multiple of the nominal base parameters
    # ddP_r's force-axis acceleration: "desired" (S ddP_d, default: Slotine & Li's reference acceleration is
    # made of reference signals, and the measured one's noise made the estimate drift) or "measured" (eq. 12's)
    psi_acceleration: str = "desired"

    def __post_init__(self) -> None:
        n = check_widths("sl-adapt", self)  # k: one entry per task axis
        check_vector("sl-adapt.k", self.k, n)
        # Gamma: one per column of a closed-form regressor (REGRESSOR_WIDTH), or one per base parameter of a chain:
        # the plant decides, so the controller checks the count against it
        check_vector("sl-adapt.gamma", self.gamma, len(self.gamma))
        if min(self.gamma) < 0:
            raise ValueError("sl-adapt.gamma must be non-negative (Gamma is positive semi-definite)")
        if self.psi_acceleration not in PSI_ACCELERATION:
            raise ValueError(f"sl-adapt.psi_acceleration must be one of {', '.join(PSI_ACCELERATION)}, "
                             f"got {self.psi_acceleration!r}")
        if not (np.isfinite(self.initial_estimate) and self.initial_estimate >= 0):
            raise ValueError(f"sl-adapt.initial_estimate must be finite and >= 0, got {self.initial_estimate!r}")


# --- the law's own gains layout, as Gamma is as wide as the plant's base parameters P, not a function of n: the
# shared prefix, k (n), the sample time, the psi_acceleration flag, the plant's code (ilcforce.plants.adaptive),
# the wall's frame R (n^2, dJ_X = R dJ), Gamma (P), the base columns of the plant's regressor rows (P), a_hat_0 (P),
# then the nominal plant's parameters (adaptive.law_parameters) to the end
K = G_OWN_FIRST
SAMPLE_TIME = (G_OWN_FIRST[0], G_OWN_FIRST[1] + 1, 0)
PSI_ACCELERATION_FLAG = (G_OWN_FIRST[0] + 1, G_OWN_FIRST[1] + 1, 0)
PLANT = (G_OWN_FIRST[0] + 2, G_OWN_FIRST[1] + 1, 0)
FRAME = (G_OWN_FIRST[0] + 3, G_OWN_FIRST[1] + 1, 0)
GAMMA = (G_OWN_FIRST[0] + 3, G_OWN_FIRST[1] + 1, 1)


def scratch(model: str, n: int) -> int:
    """The law's scratch after the shared diag (:func:`ilcforce.controllers.nd.diag_width`): LU of J_X (n^2),
    its pivots, dq_r, J_X^-1 sigma, ddq_r and dJ dq_r (n each), the regressor's rows (n x
    ``adaptive.regressor_row_width(n)``), the plant's work (``adaptive.work_width``)."""
    return n * n + 5 * n + n * adaptive.regressor_row_width(n) + adaptive.work_width(model, n)


def sl_adapt_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """Slotine & Li eqs. 9.25-9.27 on the task's n axes: dq_r = J_X^-1 (dX + sigma), ddq_r = J_X^-1 (ddX_r -
    R dJ dq_r), Y(q, dq, dq_r, ddq_r) on the plant's base columns, the estimate's backward-Euler step and
    tau = Y a_hat + J_X^T (k sigma + w F)."""
    n = tau.shape[0]
    nb = mem_prev.shape[1]  # the base parameters
    surface(n, k, meas, ref, gains, gains[at(PSI_ACCELERATION_FLAG, n)] > 0.5, diag)  # eqs. (8), (12)
    plant = gains[at(PLANT, n)]
    frame = at(FRAME, n)
    gamma = at(GAMMA, n)
    columns = gamma + nb
    start = columns + nb  # a_hat_0
    p = gains[start + nb:]  # the nominal plant
    ts = gains[at(SAMPLE_TIME, n)]
    o_lu = at(D_U, n) + n  # after the shared diag (diag_width)
    o_piv = o_lu + n * n
    o_r = o_piv + n  # dq_r
    o_s = o_r + n  # J_X^-1 sigma = -s
    o_rr = o_s + n  # ddq_r
    o_dj = o_rr + n  # dJ dq_r, in the plant's task coordinates
    o_y = o_dj + n  # Y (n rows)
    width = 10 * n  # adaptive.regressor_row_width(n)
    o_work = o_y + n * width
    if not lu(n, meas, at(M_JACOBIAN, n), diag[o_lu:o_piv], diag[o_piv:o_r]):
        for i in range(n):
            tau[i] = np.nan  # a singular J_X: the watchdog stops the iteration
        return 0
    for i in range(n):
        diag[o_r + i] = diag[2 * n + i]  # dX + sigma (surface's third block)
        diag[o_s + i] = diag[i]  # sigma
    lu_solve(n, diag[o_lu:o_piv], diag[o_piv:o_r], diag[o_r:o_s])
    lu_solve(n, diag[o_lu:o_piv], diag[o_piv:o_r], diag[o_s:o_rr])
    q = meas[at(M_THETA, n):at(M_THETA, n) + n]
    dq = meas[at(M_DTHETA, n):at(M_DTHETA, n) + n]
    work = diag[o_work:]
    adaptive.state_terms(plant, p, q, dq, work)
    adaptive.jacobian_rate_times(plant, p, q, dq, diag[o_r:o_s], work, diag, o_dj)  # dJ dq_r
    for i in range(n):  # ddq_r = J_X^-1 (ddX_r - R dJ dq_r), ddX_r = psi1 (surface's second block)
        f = frame + n * i
        c = 0.0
        for j in range(n):
            c += gains[f + j] * diag[o_dj + j]
        diag[o_rr + i] = diag[n + i] - c
    lu_solve(n, diag[o_lu:o_piv], diag[o_piv:o_r], diag[o_rr:o_dj])
    adaptive.regressor_rows(plant, p, q, dq, diag[o_r:o_s], diag[o_rr:o_dj], work, diag, o_y)
    last = mem_prev.shape[0] - 1
    for i in range(n):
        tau[i] = 0.0
    for r in range(nb):
        col = o_y + int(gains[columns + r])
        grad = 0.0
        for i in range(n):
            grad += diag[col + i * width] * diag[o_s + i]
        # a_hat(t_{k-1}) - a_hat_0: this iteration's previous sample, at k = 0 the last iteration's end
        before = mem_new[k - 1, r] if k > 0 else mem_prev[last, r]
        change = before + ts * gains[gamma + r] * grad  # Slotine & Li eq. 9.27, backward Euler
        if write:
            mem_new[k, r] = change
        a_hat = gains[start + r] + change
        for i in range(n):
            tau[i] += diag[col + i * width] * a_hat
    # Slotine & Li eq. 9.25: Y a_hat - K_D s with K_D = J^T k J, plus w J^T F (erratum 1)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    u = at(D_U, n)
    for i in range(n):
        diag[u + i] = gains[at(K, n) + i] * diag[i] + w * meas[at(M_FORCE, n) + i]
    add_joint_torque(n, meas, diag, u, tau)
    return 0


class SlotineLiController(MemoryController):
    name = "sl-adapt"
    law = compiled_law(sl_adapt_law)
    uses_nominal_dynamics = False
    memory_layout = {"a_hat_change": (0, 6, "a_hat - a_hat_0, base parameters (five-bar: kg m^2)")}
    #: make_controller passes the nominal plant's parameters (the regressor needs the lengths)
    needs_nominal_plant = True

    def __init__(self, n_control: int, surface, wall_sign: float, gains: SlotineLiGains, *,
                 gravity: bool = False, sample_time: float = float("nan"), nominal=None, frame=None):
        if nominal is None or not hasattr(nominal, "model"):
            raise ValueError("sl-adapt needs the nominal parameters of a plant (ilcforce.plants.MODELS)")
        n = len(surface.selection)
        self.base_parameter_names = adaptive.base_parameter_names(nominal.model, nominal)
        width = len(self.base_parameter_names)
        unit = adaptive.base_parameter_units(nominal.model)
        self.memory_layout = {"a_hat_change": (0, width, f"a_hat - a_hat_0, base parameters: {unit}")}
        super().__init__(n_control, sample_time)
        if not (np.isfinite(self.sample_time) and self.sample_time > 0):
            raise ValueError("sl-adapt needs the control sample time to integrate its adaptation")
        self._gains = self._pack(n, surface, wall_sign, gains, nominal, frame)
        self._initial = slice(at_py(GAMMA, n) + 2 * width, at_py(GAMMA, n) + 3 * width)
        self.nd_scratch = scratch(nominal.model, n)

    def _pack(self, n, surface, wall_sign, gains, nominal, frame) -> np.ndarray:
        """The law's gains (its layout: ``K`` .. ``GAMMA`` and what follows)."""
        names = self.base_parameter_names
        gamma = gains.gamma
        if adaptive.has_closed_form(nominal.model):  # Gamma per closed-form column: the base parameters' first
            if len(gamma) != REGRESSOR_WIDTH:
                raise ValueError(f"sl-adapt.gamma must have {REGRESSOR_WIDTH} entries for the {nominal.model}, one per "
                                 f"column of its closed-form regressor ({', '.join(names)}, then unused ones), "
                                 f"got {len(gamma)}")
            gamma = gamma[:len(names)]
        if len(gamma) != len(names):
            raise ValueError(f"sl-adapt.gamma must have {len(names)} entries, one per base parameter of the "
                             f"{nominal.model} ({', '.join(names)}), got {len(gains.gamma)}")
        frame = np.eye(n) if frame is None else np.asarray(frame, dtype=np.float64)
        if frame.shape != (n, n):
            raise ValueError(f"sl-adapt needs the wall's frame as an {n} x {n} matrix, got shape {frame.shape}")
        values = [*pack_common_gains(surface, wall_sign), *gains.k, self.sample_time,
                  PSI_ACCELERATION[gains.psi_acceleration], adaptive.code(nominal.model), *frame.ravel()]
        assert len(values) == at_py(GAMMA, n)
        a0 = gains.initial_estimate * adaptive.base_parameters(nominal)  # a_hat_0
        columns = np.asarray(adaptive.base_columns(nominal), dtype=np.float64)
        return np.concatenate([values, gamma, columns, a0, adaptive.law_parameters(nominal)]).astype(np.float64)

    @property
    def memory_labels(self) -> dict[str, tuple[str, ...]]:
        return {"a_hat_change": tuple(self.base_parameter_names)}

    def initial_estimate(self) -> np.ndarray:
        """a_hat_0 (the base parameters iteration 0 starts from), shape (n_base,)."""
        return self._gains[self._initial].copy()

    def gains(self) -> np.ndarray:
        return self._gains
