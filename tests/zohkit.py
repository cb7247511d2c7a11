"""The zero-order-hold reference the loop's integration is tested against (tests/test_simulate.py,
tests/test_contact_damping.py): a joint PD, held over each control interval, integrated by scipy's DOP853 at
tight tolerance on a right-hand side the test writes out itself."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


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
