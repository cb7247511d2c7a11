"""The zero-order-hold reference the loop's integration is tested against (tests/test_simulate.py,
tests/test_contact_damping.py): a joint PD, held over each control interval, integrated by scipy's DOP853 at
tight tolerance on a right-hand side the test writes out itself."""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.integrate import solve_ivp

from ilcforce.controllers.nd import M_DTHETA, M_THETA, at_py, law_signature

#: the joint PD's gains (N m / rad, N m s / rad)
KP, KD = 20.0, 1.0
_THETA, _DTHETA = at_py(M_THETA, 2), at_py(M_DTHETA, 2)


@njit(law_signature())
def pd_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """A joint PD holding the pose gains[0:2] (rad), the law :func:`pd_reference` integrates."""
    tau[0] = KP * (gains[0] - meas[_THETA]) - KD * meas[_DTHETA]
    tau[1] = KP * (gains[1] - meas[_THETA + 1]) - KD * meas[_DTHETA + 1]
    return 0


def pd_reference(rhs, robot, config, target, kp: float, kd: float) -> np.ndarray:
    """The states (theta, dtheta) on the log grid, shape (n_log, 4), from rest at the experiment's initial pose:
    tau = kp (target - theta) - kd dtheta held over each interval, one solve_ivp per interval of ``rhs(t, x, tau)``."""
    ts = config.simulation.sample_time
    x = np.concatenate([robot.inverse_kinematics(config.simulation.initial_position), [0.0, 0.0]])
    states = [x]
    for k in range(config.n_control - 1):
        tau = np.array([kp * (target[0] - x[0]) - kd * x[2], kp * (target[1] - x[1]) - kd * x[3]])
        sol = solve_ivp(rhs, (k * ts, (k + 1) * ts), x, args=(tau,), rtol=1e-11, atol=1e-13, method="DOP853")
        x = sol.y[:, -1]
        states.append(x)
    return np.array(states)[:: config.simulation.log_every]
