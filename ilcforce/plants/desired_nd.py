"""tau_d along the desired motion of an n-joint plant (docs/model.md#metrics, docs/model.md#n-dof): what Table 3's
chattering H compares the applied input with, for an n-joint chain moving in space (the spatial arm's
``desired_inputs``; a planar plant's is compiled, ilcforce.plants.desired).

The desired task motion X_d(t) (the reference, in the wall's frame) is followed in joint space from the
plant's working pose: q_d by inverse kinematics from the previous sample's q_d, dq_d = J^-1 dP_d and
ddq_d = J^-1 (ddP_d - dJ dq_d), with P = R^T X the world position; then
tau_d = M ddq_d + C dq_d + g + J_X^T (w F_d) (eq. 1 with the wall's reaction balanced) and J_X^-T tau_d.
Python over the log grid (2,001 samples for the paper's grid, a few tenths of a second); the caller
caches it per true plant.
"""

from __future__ import annotations

import numpy as np


def desired_inputs_nd(robot, frame: np.ndarray, wall_sign: float, reference_log: np.ndarray):
    """(tau_d, J_X^-T tau_d), each (n_log, n), for ``robot`` (a plant of the n-joint interface with the
    rigid-body API), the wall's frame R (n x n) and the reference on the log grid (n_log, 6 n)."""
    ref = np.asarray(reference_log, dtype=np.float64)
    n = frame.shape[0]
    tau_d = np.empty((ref.shape[0], n))
    task_d = np.empty((ref.shape[0], n))
    q = None
    for k in range(ref.shape[0]):
        P = frame.T @ ref[k, 0:n]
        dP = frame.T @ ref[k, n:2 * n]
        ddP = frame.T @ ref[k, 2 * n:3 * n]
        F = ref[k, 3 * n:4 * n]  # F_d in the wall's frame
        q = robot.inverse_kinematics(P) if q is None else robot.inverse_kinematics(P, q)
        J = robot.jacobian(q)
        dq = np.linalg.solve(J, dP)
        ddq = np.linalg.solve(J, ddP - robot.jacobian_derivative(q, dq) @ dq)
        # the force on the robot is the wall's reaction -w F_d: inverse dynamics adds J^T (w F_d)
        tau = robot.inverse_dynamics(q, dq, ddq, force_on_end_effector=frame.T @ (-wall_sign * F))
        tau_d[k] = tau
        task_d[k] = np.linalg.solve((frame @ J).T, tau)
    return tau_d, task_d
