"""PD-ILC: PD feedback plus a PD-type iterative learning law with a zero-phase Q filter.

The classic industrial ILC (Arimoto, Kawamura & Miyazaki, "Bettering operation of robots by
learning", J. Robotic Systems 1(2), 1984; the Q-filtered form of Bristow, Tharayil & Alleyne, "A
survey of iterative learning control", IEEE Control Systems Magazine 26(3), 2006, eqs. 4 and 13):

tau_j(t)     = v_j(t) + J^T k sigma_j(t) + w J^T F_j(t)                 (PD feedback + feed-forward)
v_{j+1}(t)   = Q[ v_j(t) + J_j^T(t) L sigma_j(t) ],   v_0 = 0            (Bristow et al. eq. 13)

sigma = lambda_P e_P + de_P (+ the force terms of eq. 8) is the PD-type learning signal of Arimoto
(de + Lambda e). Unlike C2 (eq. 27), whose update enters the same iteration at the same sample, the
update here is computed during iteration j (the law writes v_j + J^T L sigma_j at each sample) but
applied only in iteration j + 1, after the zero-phase low-pass Q (a Butterworth filter run forwards
and backwards, ``scipy.signal.sosfiltfilt``) has removed what the iteration's noise put into it. That
filtering needs the whole finished iteration, so it runs in ``end_iteration(record)``.

Default gains, from stated rules (not tuned against C3):
* feedback k = (10, 100) N s/m: the feedback gain of C1 and C3 (paper, Section 4.1);
* learning L = k: the feed-forward of iteration j + 1 takes over the torque the feedback had to give
  in iteration j (the "feedback-error" form of the update, Bristow et al. Section "PD-type");
* Q: 2nd-order Butterworth, cutoff 5 Hz, one decade above the reference's highest frequency
  (0.5 Hz force sine); sosfiltfilt doubles the order and cancels the phase (zero-phase Q).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.controllers.base import MemoryController, check_gravity_feedforward, check_vector, pack_gains
from ilcforce.controllers.nd import (
    D_U, G_FEEDFORWARD_SIGN, M_FORCE, add_joint_torque, at, check_widths, compiled_law, gain_offsets, joint_torque,
    nominal_gravity, surface,
)


@dataclass(frozen=True)
class PDILCGains:
    """Feedback, learning gain and Q filter of the PD-type ILC."""

    #: unit of each field ("": text, "1": dimensionless), read by ilcforce.config_units
    units: ClassVar[dict[str, str]] = {"k": "N s/m", "learning": "N s/m", "q_cutoff": "Hz", "q_order": "1",
                                       "gravity_feedforward": "1"}

    k: tuple[float, ...] = (10.0, 100.0)  # PD feedback gain diagonal on sigma, N s/m
    learning: tuple[float, ...] = (10.0, 100.0)  # learning gain L diagonal, N s/m
    q_cutoff: float = 5.0  # Q filter cutoff, Hz
    q_order: int = 2  # Butterworth order of Q (applied forwards and backwards)
    gravity_feedforward: float = 0.0  # g_ff: multiple of the nominal task gravity G_nom added to the feedback (0: none)

    def __post_init__(self) -> None:
        n = check_widths("pd-ilc", self)  # k and learning: one entry per task axis
        check_vector("pd-ilc.k", self.k, n)
        check_vector("pd-ilc.learning", self.learning, n)
        if not (math.isfinite(self.q_cutoff) and self.q_cutoff > 0):
            raise ValueError(f"pd-ilc.q_cutoff must be a positive frequency in Hz, got {self.q_cutoff!r}")
        if not (1 <= self.q_order <= 8):
            raise ValueError(f"pd-ilc.q_order must be 1..8, got {self.q_order!r}")
        check_gravity_feedforward("pd-ilc", self.gravity_feedforward)


K, LEARNING, _Q_CUTOFF, _Q_ORDER, GRAVITY_FEEDFORWARD = gain_offsets(
    PDILCGains, "k", "learning", "q_cutoff", "q_order", "gravity_feedforward")


def pd_ilc_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """tau = v_j + J^T (k sigma + w F + g_ff G_nom) on the task's n axes; writes v_j + J^T L sigma."""
    n = tau.shape[0]
    surface(n, k, meas, ref, gains, False, diag)  # eq. (8)
    w = gains[at(G_FEEDFORWARD_SIGN, n)]
    u = at(D_U, n)
    if write:
        # v_j + J^T L sigma_j: filtered by Q into v_{j+1} after the iteration (Bristow et al. eq. 13)
        for i in range(n):
            diag[u + i] = gains[at(LEARNING, n) + i] * diag[i]
        joint_torque(n, meas, diag, u, tau)
        for j in range(n):
            mem_new[k, j] = mem_prev[k, j] + tau[j]
    gff = gains[at(GRAVITY_FEEDFORWARD, n)]
    for i in range(n):  # PD feedback J^T k sigma
        diag[u + i] = gains[at(K, n) + i] * diag[i]
    joint_torque(n, meas, diag, u, tau)
    for j in range(n):
        tau[j] = mem_prev[k, j] + tau[j]
    for i in range(n):  # + J^T (w F + g_ff G_nom)
        diag[u + i] = w * meas[at(M_FORCE, n) + i] + nominal_gravity(n, meas, gff, i)
    add_joint_torque(n, meas, diag, u, tau)
    return 0


class PDILCController(MemoryController):
    name = "pd-ilc"
    law = compiled_law(pd_ilc_law)
    uses_nominal_dynamics = False
    #: v: the feed-forward iteration j + 1 applies (after Q); an unfinished iteration's is unfiltered
    memory_layout = {"v": (0, 2, "N m")}  # on a planar robot; n columns on a task of n axes

    def __init__(self, n_control: int, surface, wall_sign: float, gains: PDILCGains, *,
                 gravity: bool = False, sample_time: float = float("nan")):
        self.memory_layout = {"v": (0, len(surface.selection), "N m")}
        super().__init__(n_control, sample_time)
        if not (math.isfinite(self.sample_time) and self.sample_time > 0):
            raise ValueError("pd-ilc needs the control sample time to design its Q filter")
        nyquist = 0.5 / self.sample_time
        if gains.q_cutoff >= nyquist:
            raise ValueError(f"pd-ilc.q_cutoff ({gains.q_cutoff:g} Hz) must be below the Nyquist "
                             f"frequency {nyquist:g} Hz of the control sample time")
        from scipy.signal import butter  # here, not at import: the registry imports every method module

        self.uses_nominal_dynamics = gains.gravity_feedforward != 0.0  # the simulator then fills G_nom
        self._q_sos = butter(gains.q_order, gains.q_cutoff, fs=1.0 / self.sample_time, output="sos")
        self._gains = pack_gains(surface, wall_sign, gains)

    def gains(self) -> np.ndarray:
        return self._gains

    def end_iteration(self, record) -> None:
        """v_{j+1} = Q[v_j + J^T L sigma_j] over the finished iteration (zero phase), then swap."""
        if record.diverged:
            return
        from scipy.signal import sosfiltfilt

        self._new[...] = sosfiltfilt(self._q_sos, self._new, axis=0)  # Bristow et al. eq. 13
        super().end_iteration(record)
