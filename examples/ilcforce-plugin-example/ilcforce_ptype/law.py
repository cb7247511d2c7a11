"""P-type ILC with proportional feedback on the sliding surface sigma (eq. 8 of the paper):

    tau_j = v_j + J^T (k_p sigma_j + w F_j),   v_j(t) = v_{j-1}(t) + J^T gamma sigma_j(t),   v_{-1} = 0.

The contract is ilcforce's (ilcforce/controllers/base.py): a law with the fixed signature, compiled by
ilcforce on first use (``compiled_law``), and a controller object that packs the gains and owns the
memory (``MemoryController``). This law is 2-D only (the planar five-bar and serial arms); a law for
n axes is a second function, ``law_nd = compiled_law_nd(...)``, as ilcforce/controllers/c2.py has.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit
from ilcforce.controllers.base import (
    DIAG_SIGMA, GAIN_FEEDFORWARD_SIGN, MEAS_FORCE, MemoryController, check_vector, compiled_law, gain_indices,
    joint_torque, pack_gains, surface_terms,
)
from ilcforce.controllers.nd import check_widths


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


GAMMA, KP = gain_indices(PTypeGains, "gamma", "kp")  # where each gain sits in the packed vector


@njit(inline="always", error_model="numpy")
def _torque(k, meas, ref, gains, mem_prev, mem_new, write, diag):
    sx, sy, _p1x, _p1y, _p2x, _p2y = surface_terms(k, meas, ref, gains, False)  # sigma, eq. (8)
    lx, ly = joint_torque(meas, gains[GAMMA] * sx, gains[GAMMA + 1] * sy)
    v1 = mem_prev[k, 0] + lx  # v_j = v_{j-1} + J^T gamma sigma_j
    v2 = mem_prev[k, 1] + ly
    if write:
        mem_new[k, 0] = v1
        mem_new[k, 1] = v2
    w = gains[GAIN_FEEDFORWARD_SIGN]
    fx, fy = joint_torque(meas, gains[KP] * sx + w * meas[MEAS_FORCE], gains[KP + 1] * sy + w * meas[MEAS_FORCE + 1])
    diag[DIAG_SIGMA] = sx
    diag[DIAG_SIGMA + 1] = sy
    return v1 + fx, v2 + fy  # tau_j = v_j + J^T (k_p sigma_j + w F_j)


def ptype_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return _torque(k, meas, ref, gains, mem_prev, mem_new, write, diag)


class PTypeController(MemoryController):
    name = "p-ilc"  # the registry's name
    law = compiled_law(ptype_law)
    uses_nominal_dynamics = False  # reads no nominal D, C, G
    memory_layout = {"v": (0, 2, "N m")}  # the learned torque, stored as /memory/v

    def __init__(self, n_control: int, surface, wall_sign: float, gains: PTypeGains, *, gravity: bool = False,
                 sample_time: float = float("nan")):
        super().__init__(n_control, sample_time)
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains
