"""A planar plant's reference inverse dynamics, compiled (docs/model.md#metrics): tau_d and J^-T tau_d along
the desired motion, for Table 3's H and the logs' ``desired_torque``. The planar plants'
``desired_inputs`` (:class:`ilcforce.plants.base.Plant`) call it; it reaches the plant only through the
kernel signatures of :mod:`ilcforce.plants.base`. An n-joint chain's is :mod:`ilcforce.plants.desired_nd`.
"""

from __future__ import annotations

import math

import numpy as np

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import Sig, njit  # numba's, imported only when this runs through numba (ilcforce/compiled/jit.py)
from ilcforce.plants.kernel_types import kernel_type


def _desired_signature():
    """The kernel's numba signature (made when numba is imported)."""
    types = _jit.numba().types
    return types.int64(
        kernel_type("DYN"), kernel_type("IK"), types.intp,  # the plant's joint-space model, inverse kinematics,
        #                                                     parameters (address)
        types.float64[:, ::1],  # reference (n, 12), ilcforce.task layout
        types.float64,  # w, the wall's force sign
        types.float64[:, ::1],  # out: tau_d (n, 2)
        types.float64[:, ::1],  # out: J^-T tau_d (n, 2)
    )


@njit(Sig(_desired_signature), cache=True, error_model="numpy", nogil=True)
def desired_kernel(dyn, ik, p, ref, w, tau_d, task_d):
    """tau_d = Dq ddtheta_d + Cq dtheta_d + G_q - J^T f_d along the reference (eq. 1), f_d = -w F_d
    the wall's reaction to the desired force; and J^-T tau_d, with dtheta_d = J^-1 dP_d and
    ddtheta_d = J^-1 (ddP_d - dJ dtheta_d). Returns -1, or the first row whose P_d is outside the
    plant's working mode (the rest is then unset).

    The solves and products are numba's np.linalg.solve and @ (LAPACK and BLAS, as numpy's), in
    the order of the plant's public API, so the numbers are those of the readable Python loop.
    """
    J = np.empty((2, 2))
    Jt = np.empty((2, 2))
    dJ = np.empty((2, 2))
    Dq = np.empty((2, 2))
    Cq = np.empty((2, 2))
    v = np.empty(2)
    acc = np.empty(2)
    f = np.empty(2)
    g = np.empty(2)
    for i in range(ref.shape[0]):
        px, py = ref[i, 0], ref[i, 1]
        ok, th1, th2 = ik(p, px, py)
        if ok == 0.0:
            return i
        o = dyn(p, th1, th2, 0.0, 0.0)
        if o[0] == 0.0 or math.hypot(o[1] - px, o[2] - py) > 1e-9:  # the IK's pose must map back to P_d
            return i
        J[0, 0], J[0, 1], J[1, 0], J[1, 1] = o[3], o[4], o[5], o[6]
        Jt[0, 0], Jt[0, 1], Jt[1, 0], Jt[1, 1] = o[3], o[5], o[4], o[6]
        v[0], v[1] = ref[i, 2], ref[i, 3]
        dtheta = np.linalg.solve(J, v)
        o = dyn(p, th1, th2, dtheta[0], dtheta[1])
        dJ[0, 0], dJ[0, 1], dJ[1, 0], dJ[1, 1] = o[7], o[8], o[9], o[10]
        Dq[0, 0], Dq[0, 1], Dq[1, 0], Dq[1, 1] = o[11], o[12], o[12], o[13]
        Cq[0, 0], Cq[0, 1], Cq[1, 0], Cq[1, 1] = o[14], o[15], o[16], o[17]
        g[0], g[1] = o[18], o[19]
        acc[0], acc[1] = ref[i, 4], ref[i, 5]
        ddtheta = np.linalg.solve(J, acc - dJ @ dtheta)
        f[0], f[1] = -w * ref[i, 6], -w * ref[i, 7]  # the force on the robot: the wall's reaction
        tau = Dq @ ddtheta + Cq @ dtheta - Jt @ f + g  # eq. (1)
        tau_d[i, 0], tau_d[i, 1] = tau[0], tau[1]
        x = np.linalg.solve(Jt, tau)  # J^-T tau_d
        task_d[i, 0], task_d[i, 1] = x[0], x[1]
    return -1
