"""C3: the paper's ILC based on the sliding mode technique, eq. (14) (docs/model.md#c3).

tau_j = J^T (k sigma_j + Phi_j^T Theta_hat_j + w F_j + alpha_hat_j sgn(sigma_j))
Theta_hat_j(t) = Theta_hat_{j-1}(t) + Gamma Phi_j(t) sigma_j(t),    Theta_hat_{-1} = 0
alpha_hat_j(t) = alpha_hat_{j-1}(t) + eta sigma_j(t)^T sgn(sigma_j(t)),  alpha_hat_{-1} = 0

With G = 0 (erratum 3, the five-bar): Psi = [psi1; dP + sigma] in R^4, Phi = blockdiag(Psi, Psi) in
R^(8x2), Theta = [D11 D12 C11 C12 D21 D22 C21 C22], so Phi^T Theta = D psi1 + C (dP + sigma).
With a plant that has gravity (docs/model.md#serial2r, decided from the plant): the paper's full form, eqs. (12)-(13),
Psi = [psi1; dP + sigma; 1 1] in R^6 (Xi = [D C G]^T in R^(3n x n), G's block applied to the ones
vector), Theta = [D11 D12 C11 C12 G11 G12 D21 D22 C21 C22 G21 G22] in R^12 = R^(3n^2), so
Phi^T Theta = D psi1 + C (dP + sigma) + G 1, and the learned G_i1 + G_i2 estimates the task gravity G_i.

``gravity_feedforward`` (g_ff, default 0: the paper's law) adds g_ff G_nom, the nominal model's task
gravity at the measured angles, inside J^T(...): Theta's G block then learns only what the nominal
model gets wrong (e.g. the 2R arm's m2 x 1.4), not the whole load (``ilcforce.plants.serial2r``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.controllers.base import MemoryController, check_gravity_feedforward, check_vector, pack_gains, sgn
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, M_FORCE, at, check_widths, compiled_law, gain_offsets, joint_torque, nominal_gravity,
    surface,
)

PSI_ACCELERATION = {"measured": 0.0, "desired": 1.0}


@dataclass(frozen=True)
class C3Gains:
    """Gains of eq. (14) (Section 4.1)."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "eta": "N s/m",
                                       "gamma": "mixed: kg s^3/m^2 (D entries), kg s/m^2 (C entries)",
                                       "gamma_gravity": "N s/m", "psi_acceleration": "", "gravity_feedforward": "1"}

    k: tuple[float, ...] = (10.0, 100.0)  # feedback gain diagonal, N s/m
    eta: float = 5.0  # learning rate of the switching gain
    gamma: tuple[float, ...] = (4e3, 40.0, 1e4, 1e4, 1e3, 1e3, 1e4, 1e4)  # Gamma diagonal, Theta order
    # Gamma for Theta's G block (G11 G12 G21 G22), used only with a plant that has gravity (the paper
    # gives no value, docs/model.md#c3): the paper's D21/D22 gains. Each G entry adds gamma * sigma to the
    # current-iteration feedback: Ts * 2 gamma / lambda_min(D) = 0.67 on the 2R arm's path
    # (lambda_min(D) = 0.30 kg, Ts = 0.1 ms), below the sampled loop's limit 2; 3e3 diverges at once
    gamma_gravity: tuple[float, ...] = (1e3, 1e3, 1e3, 1e3)
    psi_acceleration: str = "measured"  # "measured": S ddP in Psi (the paper); "desired": S ddP_d
    gravity_feedforward: float = 0.0  # g_ff: multiple of the nominal task gravity G_nom added (0: the paper's law)

    #: the config section these gains come from, named in error messages (C3-leak inherits them)
    section: ClassVar[str] = "c3"

    def __post_init__(self) -> None:
        name = self.section
        n = check_widths(name, self)  # k: n entries, gamma: 2 n^2, gamma_gravity: n^2
        check_vector(f"{name}.k", self.k, n)
        check_vector(f"{name}.gamma", self.gamma, 2 * n * n)
        check_vector(f"{name}.gamma_gravity", self.gamma_gravity, n * n)
        if min(self.gamma_gravity) < 0:
            raise ValueError(f"{name}.gamma_gravity must be non-negative (Gamma is positive semi-definite)")
        if not (np.isfinite(self.eta) and self.eta >= 0):
            raise ValueError(f"{name}.eta must be finite and >= 0, got {self.eta!r}")
        if min(self.gamma) < 0:
            raise ValueError(f"{name}.gamma must be non-negative (Gamma is positive semi-definite)")
        check_gravity_feedforward(name, self.gravity_feedforward)
        if self.psi_acceleration not in PSI_ACCELERATION:
            raise ValueError(f"{name}.psi_acceleration must be one of {', '.join(PSI_ACCELERATION)}, "
                             f"got {self.psi_acceleration!r}")


K, ETA, GAMMA, GAMMA_GRAVITY, PSI_ACCELERATION_FLAG, GRAVITY_FEEDFORWARD = gain_offsets(
    C3Gains, "k", "eta", "gamma", "gamma_gravity", "psi_acceleration", "gravity_feedforward")


@njit(inline="always", error_model="numpy")
def alpha_update(previous, increment, alpha_max, alpha_leak, alpha_nominal):
    """alpha_hat_j(t) from alpha_hat_{j-1}(t) (``previous``) and eta sigma^T sgn(sigma) (``increment``), eq. (14):

    alpha_hat_j = min(alpha_max, alpha_hat_{j-1} - alpha_leak (alpha_hat_{j-1} - alpha_nominal) + increment)

    The leak is the sigma-modification of adaptive control (Ioannou & Kokotovic 1983) on the switching gain
    alone: with a bounded sigma, alpha_hat settles at alpha_nominal + increment / alpha_leak, learned and
    bounded without a cap. alpha_leak = 0 skips it (the arithmetic of the paper's law, bit for bit)."""
    if alpha_leak > 0.0:
        previous = previous - alpha_leak * (previous - alpha_nominal)
    alpha = previous + increment  # eq. (14), alpha update
    if alpha > alpha_max:  # (a NaN stays NaN, so the watchdog still sees a divergence)
        alpha = alpha_max
    return alpha


@njit(inline="always", error_model="numpy")
def c3_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, keep, alpha_max, learn, alpha_leak,
              alpha_nominal):
    """Eq. (14) at sample k on the task's n axes, with the previous iteration's memory scaled by ``keep``,
    alpha_hat_j capped at ``alpha_max``, and Theta_hat and alpha_hat updated only where ``learn`` is True (their
    learning signal is sigma there, 0 elsewhere); alpha_hat_{j-1} leaks towards ``alpha_nominal`` by the
    fraction ``alpha_leak`` before the update (:func:`alpha_update`). The paper's C3 is keep = 1,
    alpha_max = inf, learn = True, alpha_leak = 0 (all exact no-ops); C3-leak (``c3_leak``) uses
    keep = 1 - leakage and a finite bound; C3-robust (``c3_robust``) a bound, a learning window and
    optionally the leak of alpha_hat.

    Psi = [psi1; dP + sigma; 1] in R^(3n) with gravity (na = 3n entries of Theta per axis), [psi1; dP +
    sigma] in R^(2n) without (na = 2n); the memory is Theta_hat axis by axis (n na columns), then alpha_hat.
    Theta row r of axis i has Gamma entry gamma[2 n i + r] (r < 2n) or gamma_gravity[n i + r - 2n]."""
    n = tau.shape[0]
    psi_desired = gains[at(PSI_ACCELERATION_FLAG, n)] > 0.5
    surface(n, k, meas, ref, gains, psi_desired, diag)
    na = (mem_prev.shape[1] - 1) // n
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    u = at(D_U, n)
    gamma = at(GAMMA, n)
    gamma_g = at(GAMMA_GRAVITY, n)
    gff = gains[at(GRAVITY_FEEDFORWARD, n)]
    a_sum = 0.0
    for i in range(n):
        sigma = diag[i]
        l = sigma if learn else 0.0  # sigma as the updates of eq. (14) see it
        m = 0.0
        for r in range(na):
            if r < 2 * n:
                psi = diag[n + r]  # psi1 (r < n), then dP + sigma: diag's next block           eq. (12)
                g = gains[gamma + 2 * n * i + r]
            else:
                psi = 1.0  # the G block: Psi's third block is the ones vector (eq. 12)
                g = gains[gamma_g + n * i + r - 2 * n]
            th = keep * mem_prev[k, na * i + r] + g * psi * l  # eq. (14), Theta update
            m += th * psi if r < 2 * n else th
            if write:
                mem_new[k, na * i + r] = th
        a_sum += l * sgn(l)
        diag[u + i] = m
    alpha = alpha_update(keep * mem_prev[k, n * na], gains[at(ETA, n)] * a_sum, alpha_max, alpha_leak, alpha_nominal)
    if write:
        mem_new[k, n * na] = alpha
    for i in range(n):
        sigma = diag[i]
        # eq. (14), control law with +w F (erratum 1)
        diag[u + i] = (gains[at(K, n) + i] * sigma + diag[u + i] + w * meas[at(M_FORCE, n) + i] + alpha * sgn(sigma)
                       + nominal_gravity(n, meas, gff, i))
    joint_torque(n, meas, diag, u, tau)
    return 0


def c3_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    return c3_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, 1.0, np.inf, True, 0.0, 0.0)


class C3Controller(MemoryController):
    name = "c3"
    law = compiled_law(c3_law)
    uses_nominal_dynamics = False
    #: on a planar robot without gravity; in general n axes of na Theta entries each, then alpha_hat (__init__)
    memory_layout = {"theta_hat": (0, 8, "mixed: kg (D entries), kg/s (C entries)"), "alpha_hat": (8, 9, "N")}
    #: Theta's entries in memory order (a planar robot, G = 0)
    theta_names = ("D11", "D12", "C11", "C12", "D21", "D22", "C21", "C22")

    @property
    def memory_labels(self) -> dict[str, tuple[str, ...]]:
        """Theta_hat's column labels for the store (D11 D12 C11 C12 ...; G entries with gravity)."""
        return {"theta_hat": tuple(self.theta_names)}

    def __init__(self, n_control: int, surface, wall_sign: float, gains: C3Gains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        # Theta in R^(2 n^2), or R^(3 n^2) with the G block of eq. (13) when the plant has gravity
        # (docs/model.md#serial2r, docs/model.md#n-dof): n axes of na entries, then alpha_hat; the law reads na from
        # the memory width. On a planar robot: D11 D12 C11 C12 (G11 G12) D21 D22 C21 C22 (G21 G22), alpha_hat
        n = len(surface.selection)
        na = 3 * n if gravity else 2 * n
        blocks = ("D", "C", "G") if gravity else ("D", "C")
        unit = "mixed: kg (D entries), kg/s (C entries)" + (", N (G entries)" if gravity else "")
        self.memory_layout = {"theta_hat": (0, n * na, unit), "alpha_hat": (n * na, n * na + 1, "N")}
        self.theta_names = tuple(f"{b}{i + 1}{j + 1}" for i in range(n) for b in blocks for j in range(n))
        super().__init__(n_control, sample_time)
        self.uses_nominal_dynamics = gains.gravity_feedforward != 0.0  # the simulator then fills G_nom
        # gains by name: gamma_gravity is packed whether or not the plant has gravity (fixed layout)
        self._gains = pack_gains(surface, wall_sign, gains, encode={"psi_acceleration": PSI_ACCELERATION})

    def gains(self) -> np.ndarray:
        return self._gains
