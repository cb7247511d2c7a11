"""P-type ILC with proportional feedback on the sliding surface sigma (eq. 8 of the paper):

    tau_j = v_j + J^T (k_p sigma_j + w F_j),   v_j(t) = v_{j-1}(t) + J^T gamma sigma_j(t),   v_{-1} = 0.

The contract is ilcforce's (ilcforce/controllers/base.py): one law with the fixed signature, compiled by
ilcforce on first use (``compiled_law``), which serves a task of any number of axes n (n = 2 on the
planar robots, 3 on the spatial arm: it reads n from tau), and a controller object that packs the gains
and owns the memory (``MemoryController``). ilcforce/controllers/c2.py is the shipped law closest to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.controllers.base import MemoryController, check_vector, pack_gains
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, M_FORCE, add_joint_torque, at, check_widths, compiled_law, gain_offsets, joint_torque,
    surface,
)


@dataclass(frozen=True)
class PTypeGains:
    """The method's gains: the TOML section [p-ilc] (``--set p-ilc.gamma=[300, 300]``)."""

    #: unit of each field, read by ilcforce's configuration display
    units: ClassVar[dict[str, str]] = {"gamma": "N s/m", "kp": "N s/m"}

    gamma: tuple[float, ...] = (300.0, 300.0)  # learning gain per task axis, N s/m
    kp: tuple[float, ...] = (100.0, 100.0)  # feedback gain per task axis, N s/m

    def __post_init__(self) -> None:
        check_widths("p-ilc", self)  # one entry per task axis
        check_vector("p-ilc.gamma", self.gamma, len(self.gamma))
        check_vector("p-ilc.kp", self.kp, len(self.kp))


GAMMA, KP = gain_offsets(PTypeGains, "gamma", "kp")  # where each gain sits in the packed vector (read with at)


def ptype_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    n = tau.shape[0]  # the task's axes
    surface(n, k, meas, ref, gains, False, diag)  # sigma (eq. 8) into diag[:n]
    u = at(D_U, n)  # diag's scratch for a task-space command
    for i in range(n):
        diag[u + i] = gains[at(GAMMA, n) + i] * diag[i]
    joint_torque(n, meas, diag, u, tau)  # J^T gamma sigma_j
    for j in range(n):
        v = mem_prev[k, j] + tau[j]  # v_j = v_{j-1} + J^T gamma sigma_j
        if write:
            mem_new[k, j] = v
        tau[j] = v
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    for i in range(n):
        diag[u + i] = gains[at(KP, n) + i] * diag[i] + w * meas[at(M_FORCE, n) + i]
    add_joint_torque(n, meas, diag, u, tau)  # tau_j = v_j + J^T (k_p sigma_j + w F_j)
    return 0


class PTypeController(MemoryController):
    name = "p-ilc"  # the registry's name
    law = compiled_law(ptype_law)
    uses_nominal_dynamics = False  # reads no nominal D, C, G
    memory_layout = {"v": (0, 2, "N m")}  # the learned torque, stored as /memory/v (n columns for n axes)

    def __init__(self, n_control: int, surface, wall_sign: float, gains: PTypeGains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        self.memory_layout = {"v": (0, len(surface.selection), "N m")}
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
