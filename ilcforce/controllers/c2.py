"""C2: traditional ILC of Azenha (2000), eq. (27) (docs/model.md#c2).

tau_j = v_j + w J^T F_j,  v_j(t) = v_{j-1}(t) + J_j^T k sigma_j(t),  v_{-1} = 0.
The update is current-iteration: this iteration's sigma enters this iteration's v at the same sample.

``gravity_feedforward`` (g_ff, default 0: the paper's law) adds g_ff J^T G_nom, the nominal model's
task-space gravity at the measured angles, to tau_j: on a robot with gravity (docs/model.md#serial2r) the learning
then starts from the nominal gravity load instead of from nothing (see ``ilcforce.plants.serial2r``
for why the serial 2R arm's experiment needs it); on the five-bar G_nom = 0 and it changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit
from ilcforce.controllers.base import MemoryController, check_gravity_feedforward, check_vector, pack_gains
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, M_FORCE, add_joint_torque, at, check_widths, compiled_law, gain_offsets, joint_torque,
    nominal_gravity, surface,
)


@dataclass(frozen=True)
class C2Gains:
    """Gains of eq. (27)."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "gravity_feedforward": "1"}

    k: tuple[float, ...] = (400.0, 400.0)  # learning gain diagonal, N s/m
    gravity_feedforward: float = 0.0  # g_ff: multiple of the nominal task gravity G_nom added (0: the paper's law)

    def __post_init__(self) -> None:
        check_widths("c2", self)  # k: one entry per task axis
        check_vector("c2.k", self.k, len(self.k))
        check_gravity_feedforward("c2", self.gravity_feedforward)


K, GRAVITY_FEEDFORWARD = gain_offsets(C2Gains, "k", "gravity_feedforward")


@njit(inline="always", error_model="numpy")
def c2_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, learn):
    """Eq. (27) at sample k on the task's n axes. Where ``learn`` is False (C2-robust's samples before its
    learning window) the memory is carried unchanged and J^T k sigma acts as feedback only; the paper's C2 is
    learn = True."""
    n = tau.shape[0]
    surface(n, k, meas, ref, gains, False, diag)  # eq. (8)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    u = at(D_U, n)
    gff = gains[at(GRAVITY_FEEDFORWARD, n)]
    if learn:
        for i in range(n):
            diag[u + i] = gains[at(K, n) + i] * diag[i]
        joint_torque(n, meas, diag, u, tau)  # J^T k sigma_j, learned
    for j in range(n):
        v = mem_prev[k, j] + (tau[j] if learn else 0.0)  # eq. (27), v_j = v_{j-1} + J^T k sigma_j
        if write:
            mem_new[k, j] = v
        tau[j] = v
    for i in range(n):  # +w F (erratum 1) (+ g_ff G_nom); without learning J^T k sigma as feedback
        f = w * meas[at(M_FORCE, n) + i] + nominal_gravity(n, meas, gff, i)
        diag[u + i] = f if learn else f + gains[at(K, n) + i] * diag[i]
    add_joint_torque(n, meas, diag, u, tau)  # eq. (27), tau_j = v_j + w J^T F_j
    return 0


def c2_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    return c2_torque(k, meas, ref, gains, mem_prev, mem_new, write, diag, tau, True)


class C2Controller(MemoryController):
    name = "c2"
    law = compiled_law(c2_law)
    uses_nominal_dynamics = False
    memory_layout = {"v": (0, 2, "N m")}  # on a planar robot; n columns on a task of n axes

    def __init__(self, n_control: int, surface, wall_sign: float, gains: C2Gains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        self.memory_layout = {"v": (0, len(surface.selection), "N m")}
        super().__init__(n_control, sample_time)
        self.uses_nominal_dynamics = gains.gravity_feedforward != 0.0  # the simulator then fills G_nom
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
