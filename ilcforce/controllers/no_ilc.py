"""NO-ILC: norm-optimal iterative learning control on the lifted model of the nominal closed loop.

The update of Amann, Owens & Rogers ("Iterative learning control for discrete-time systems with
exponential rate of convergence", IEE Proc. Control Theory Appl. 143(2), 1996): after iteration j the
feed-forward of iteration j + 1 minimises

    J(u_{j+1}) = ||e_{j+1}||_Q^2 + ||u_{j+1} - u_j||_R^2,   e_{j+1} = e_j - G (u_{j+1} - u_j)

on the lifted model G of the nominal plant, whose minimiser is

    u_{j+1} = u_j + (G^T Q G + R)^-1 G^T Q e_j                                  (docs/methods.md#no-ilc)

followed by a zero-phase low-pass Q filter on the memory, as the robust variants apply theirs
(``ilcforce.controllers.robust``). Within an iteration the law is

    tau_j(t) = J^T [ u_j(t) + k sigma_j(t) + w F_j(t) + g_ff G_nom ]

sigma of eq. (8), u_j the learned task-space feed-forward (n axes) of iteration j. The feedback part
is PD-ILC's (``ilcforce.controllers.pd_ilc``): it is smooth, so the closed loop has a derivative in u
that finite differences measure (C1's sgn sigma has none: a secant of a switch is no linearisation, see
``ilcforce.theory.lifted``), and it is the simplest feedback every robot here already runs under.

**The basis.** The feed-forward's change is parametrised on M piecewise-linear hat functions per task
axis, their knots evenly spaced over the horizon ``knot_spacing`` apart (M = duration / spacing + 1):
u_{j+1} - u_j = Phi dc, Phi (n_control x M) per axis. So G is (n n_log x n M), e taken on the log grid,
and is built once per process and setting, before the first update, by finite differences of the
noise-free nominal closed loop (``ilcforce.theory.norm_optimal``). In the coefficients the update is

    dc_j = (G^T Q G + R)^-1 G^T Q e_j,   R = r diag(rho_1 I, ..., rho_n I)

with Q = diag(q_position on position axes, q_force on the force axis) and rho_i the median over axis
i's basis functions of the weighted error one unit of one coefficient makes (:func:`norm_optimal_gain`):
``r`` is unitless, and one basis function's own error is corrected by about 1 / (1 + r) per iteration
on every axis, whatever the axes' units and weights.

**The error is measured.** The law writes, beside the feed-forward it ran, the error a controller can
measure: Sbar (P_d - P_meas) + S (F_d - F_meas), P_meas from the nominal kinematics of the encoder
reading (eq. 6, eq. 7). The update reads it from the memory after the iteration, never the true state.

Default gains, from stated rules (not tuned):
* k = (10, 100) N s/m: PD-ILC's and C1's feedback gain (paper, Section 4.1);
* q_position = 1.8e8 1/m^2, q_force = 1 1/N^2: the paper's settled 2-norms of C3 (Table 2: 4.3e-6 m and
  0.058 N) weigh the same, (0.058 / 4.3e-6)^2 = 1.8e8 (only the ratio matters: R scales with Q);
* r = 0.1: a typical basis function's error is corrected by about 91% per iteration, weaker directions
  of G less (the regularisation that leaves room for the model error, e.g. the m3 change at j = 10);
* q_cutoff = 5 Hz, order 2: PD-ILC's Q, one decade above the reference's highest frequency;
* knot_spacing = 20 ms: hat functions that resolve the feed-forward to about 25 Hz, above the Q filter's
  cutoff; on the paper's 2 s horizon M = 101 per axis, so G costs n x 101 + 1 simulated iterations.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.controllers.base import MemoryController, check_gravity_feedforward, check_vector, pack_gains
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, G_SELECTION, M_FORCE, M_POSITION, R_FORCE, R_POSITION, at, check_widths,
    compiled_law, gain_offsets, joint_torque, nominal_gravity, surface,
)
from ilcforce.controllers.robust import QFilter, check_robust_gains

#: the largest basis a G may have, per task axis (one simulated iteration per basis function and axis)
MAX_KNOTS = 2000


@dataclass(frozen=True)
class NOILCGains:
    """Feedback, weights, basis and Q filter of the norm-optimal ILC."""

    section: ClassVar[str] = "no-ilc"
    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "q_position": "1/m^2", "q_force": "1/N^2", "r": "1",
                                       "knot_spacing": "s", "q_cutoff": "Hz", "q_order": "1",
                                       "gravity_feedforward": "1"}

    k: tuple[float, ...] = (10.0, 100.0)  # feedback gain diagonal on sigma, N s/m
    q_position: float = 1.8e8  # Q on the position-controlled axes' error, 1/m^2
    q_force: float = 1.0  # Q on the force-controlled axis' error, 1/N^2
    r: float = 0.1  # R relative to a typical basis function's weighted reach (> 0, unitless)
    knot_spacing: float = 0.02  # time between the knots of the hat functions, s (M = duration / spacing + 1)
    q_cutoff: float = 5.0  # Q filter cutoff, Hz (0: no filter)
    q_order: int = 2  # Butterworth order of Q (run forwards and backwards)
    gravity_feedforward: float = 0.0  # g_ff: multiple of the nominal task gravity G_nom added to the feedback (0: none)

    def __post_init__(self) -> None:
        n = check_widths(self.section, self)  # k: one entry per task axis
        check_vector(f"{self.section}.k", self.k, n)
        for name in ("q_position", "q_force"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{self.section}.{name} must be a finite weight >= 0, got {value!r}")
        if self.q_position == 0 and self.q_force == 0:
            raise ValueError(f"{self.section}.q_position and q_force are both 0: the update would minimise nothing")
        if not (math.isfinite(self.r) and self.r > 0):
            raise ValueError(f"{self.section}.r must be a finite number > 0 (R relative to a basis function's reach), "
                             f"got {self.r!r}")
        if not (math.isfinite(self.knot_spacing) and self.knot_spacing > 0):
            raise ValueError(f"{self.section}.knot_spacing must be a time > 0 s, got {self.knot_spacing!r}")
        check_robust_gains(self.section, 0.0, self.q_cutoff, self.q_order)
        check_gravity_feedforward(self.section, self.gravity_feedforward)


(K, _Q_POSITION, _Q_FORCE, _R, _KNOT_SPACING, _Q_CUTOFF, _Q_ORDER,
 GRAVITY_FEEDFORWARD) = gain_offsets(NOILCGains, "k", "q_position", "q_force", "r", "knot_spacing", "q_cutoff",
                                        "q_order", "gravity_feedforward")


def no_ilc_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """tau = J^T (u_j + k sigma + w F + g_ff G_nom); writes u_j and the measured error e_j (n axes each)."""
    n = tau.shape[0]
    surface(n, k, meas, ref, gains, False, diag)  # eq. (8)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    gff = gains[at(GRAVITY_FEEDFORWARD, n)]
    u = at(D_U, n)
    for i in range(n):
        # (N3): learned feed-forward u_j + PD feedback k sigma + force feed-forward w F (+ g_ff G_nom)
        diag[u + i] = (mem_prev[k, i] + gains[at(K, n) + i] * diag[i] + w * meas[at(M_FORCE, n) + i]
                       + nominal_gravity(n, meas, gff, i))
    if write:
        for i in range(n):
            s = gains[at(G_SELECTION, n) + i]
            e_p = (1.0 - s) * (ref[k, R_POSITION * n + i] - meas[at(M_POSITION, n) + i])  # eq. (6), measured
            e_f = s * (ref[k, R_FORCE * n + i] - meas[at(M_FORCE, n) + i])  # eq. (7), measured
            mem_new[k, i] = mem_prev[k, i]
            mem_new[k, n + i] = e_p + e_f
    joint_torque(n, meas, diag, u, tau)
    return 0


# --- the update (pure numpy: the unit tests run it on systems whose solution is known) -----------------

def hat_basis(n_samples: int, knots: int) -> np.ndarray:
    """Phi, (n_samples, knots): piecewise-linear hat functions at ``knots`` evenly spaced knots over the
    samples (the first at sample 0, the last at n_samples - 1); each row sums to 1."""
    grid = np.linspace(0.0, 1.0, n_samples)
    nodes = np.linspace(0.0, 1.0, knots)
    return np.column_stack([np.interp(grid, nodes, np.eye(knots)[m]) for m in range(knots)])


def norm_optimal_gain(model: np.ndarray, weights: np.ndarray, r: float, axes: int = 1) -> np.ndarray:
    """L = (G^T Q G + R)^-1 G^T Q, Q = diag(weights), R = r diag(rho_1 I, ..., rho_axes I).

    ``model`` G (n_err, n_coef), its coefficients in ``axes`` equal blocks (one per task axis, axis-major);
    rho_i is the median over axis i's basis functions of ||G_c||_Q^2, the weighted error one unit of one
    coefficient makes (the median diagonal entry of G_i^T Q G_i): the reach of a typical basis function,
    not swayed by the few near the start whose reach is many times larger. Each axis' feed-forward is
    so held back relative to its own reach, whatever the units and weights of the axes: one basis
    function's own error is corrected by about 1 / (1 + r) per iteration. ``weights`` (n_err,) >= 0, r > 0;
    returns L (n_coef, n_err): the update is dc = L e (Amann, Owens & Rogers 1996)."""
    model = np.asarray(model, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if model.ndim != 2 or weights.shape != (model.shape[0],) or model.shape[1] % axes:
        raise ValueError(f"model must be (n_err, n_coef) with n_coef a multiple of {axes}, and weights (n_err,); "
                         f"got {model.shape} and {weights.shape}")
    weighted = model * weights[:, None]  # Q G
    normal = model.T @ weighted  # G^T Q G
    size = model.shape[1] // axes
    for i in range(axes):
        block = slice(i * size, (i + 1) * size)
        scale = float(np.median(np.diag(normal)[block]))
        if not scale > 0:
            raise ValueError(f"the lifted model is zero on axis {i + 1}: its feed-forward does not reach the "
                             "weighted error (a weight of 0 on the only axis it moves?)")
        normal[block, block] += r * scale * np.eye(size)  # + R
    return np.linalg.solve(normal, weighted.T)  # (N4), docs/methods.md#no-ilc


def knot_count(section: str, n_control: int, sample_time: float, spacing: float) -> int:
    """M, the hat functions per axis: the horizon over ``spacing`` plus one (at least 2), or ValueError (one
    line) if that is more than :data:`MAX_KNOTS` or the spacing is below the sample time."""
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise ValueError(f"{section} needs the control sample time to place its knots")
    if spacing < sample_time:
        raise ValueError(f"{section}.knot_spacing ({spacing:g} s) must be at least the control sample time "
                         f"{sample_time:g} s")
    knots = max(2, int(round((n_control - 1) * sample_time / spacing)) + 1)
    if knots > MAX_KNOTS:
        raise ValueError(f"{section}.knot_spacing ({spacing:g} s) gives {knots} knots per axis over the horizon; "
                         f"at most {MAX_KNOTS} (one simulated iteration each to build G)")
    return knots


class NOILCController(MemoryController):
    """Norm-optimal ILC: the law above, the update between iterations (``end_iteration``)."""

    name = "no-ilc"
    law = compiled_law(no_ilc_law)
    uses_nominal_dynamics = False
    #: u: the feed-forward iteration j + 1 applies (after the update and Q); error: the measured error of
    #: iteration j that made it (Sbar e_P + S e_F, m on position axes, N on the force axis)
    memory_layout = {"u": (0, 2, "N"), "error": (2, 4, "m or N")}
    #: make_controller hands such a controller the nominal closed loop's lifted map (ilcforce.theory.norm_optimal)
    needs_lifted_model = True

    def __init__(self, n_control: int, surface, wall_sign: float, gains: NOILCGains, *, gravity: bool = False,
                 sample_time: float = float("nan"), lifted_model: Callable | None = None, log_every: int = 1):
        n = len(surface.selection)
        self.memory_layout = {"u": (0, n, "N"), "error": (n, 2 * n, "m or N")}
        super().__init__(n_control, sample_time)
        self.n = n
        self.settings = gains
        self.log_every = int(log_every)
        self.uses_nominal_dynamics = gains.gravity_feedforward != 0.0  # the simulator then fills G_nom
        self._q = QFilter(gains.section, gains.q_cutoff, gains.q_order, self.sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)
        selection = np.asarray(surface.selection, dtype=np.float64)
        axis_weights = (1.0 - selection) * gains.q_position + selection * gains.q_force
        self._error_rows = np.arange(0, n_control, self.log_every)  # e on the log grid
        self._weights = np.tile(axis_weights, self._error_rows.size)  # sample-major, as e.ravel()
        #: M: hat functions per axis; Phi is never made (n_control x M), its product is an interpolation
        self.knots = knot_count(gains.section, n_control, self.sample_time, gains.knot_spacing)
        self._grid, self._nodes = np.linspace(0.0, 1.0, n_control), np.linspace(0.0, 1.0, self.knots)
        self._lifted_model = lifted_model
        self._update = None  # L, made at the first update

    def gains(self) -> np.ndarray:
        return self._gains

    def error_vector(self, memory: np.ndarray) -> np.ndarray:
        """e (n_log n,), sample-major, from a memory an iteration wrote: its measured error on the log grid."""
        return memory[self._error_rows, self.n:2 * self.n].ravel()

    def feedforward(self, coefficients: np.ndarray) -> np.ndarray:
        """Phi dc on the control grid, (n_control, n), from coefficients ordered axis-major (axis i: M of them):
        the piecewise-linear interpolation of each axis' coefficients at its knots (:func:`hat_basis`'s product)."""
        per_axis = np.asarray(coefficients, dtype=np.float64).reshape(self.n, self.knots)
        return np.column_stack([np.interp(self._grid, self._nodes, c) for c in per_axis])

    def update_matrix(self) -> np.ndarray:
        """L (n M, n n_log): the norm-optimal gain on the lifted model (built on first use)."""
        if self._update is None:
            if self._lifted_model is None:
                raise RuntimeError("no-ilc needs the nominal closed loop's lifted model (made by make_controller)")
            self._update = norm_optimal_gain(self._lifted_model(self), self._weights, self.settings.r, self.n)
        return self._update

    def end_iteration(self, record) -> None:
        """u_{j+1} = Q[u_j + Phi L e_j], the error of iteration j kept beside it; a diverged iteration hands
        on nothing (the base class)."""
        if record.diverged:
            return
        memory = self._new
        step = self.update_matrix() @ self.error_vector(memory)  # (N4): dc_j = (G^T Q G + R)^-1 G^T Q e_j
        memory[:, :self.n] = self._q.apply(memory[:, :self.n] + self.feedforward(step))  # (N2): Q[u_j + Phi dc_j]
        super().end_iteration(record)
