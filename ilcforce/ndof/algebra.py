"""The nominal task-space model of eq. (4) for the n-joint loop (docs/model.md#n-dof), into the law's measurement
vector, on scratch arrays it is given (no allocation); the small dense algebra it and the loop use (Cholesky, LU)
is ``ilcforce.compiled.dense``. Matrices are n x n, row-major, in flat arrays.
"""

from __future__ import annotations

from ilcforce.compiled.dense import lu, lu_solve
from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import M_TASK_CORIOLIS, M_TASK_GRAVITY, M_TASK_INERTIA, at

# offsets of the plant kernel's output (ilcforce.plants.nd: its layout as (a, b, c), offset a + b n + c n^2)
OUT_P, OUT_J = (0, 0, 0), (0, 1, 0)
OUT_DJV, OUT_M, OUT_B = (0, 1, 1), (0, 2, 1), (0, 2, 2)
OUT_CQ, OUT_G, OUT_DJ = (0, 3, 2), (0, 3, 3), (0, 4, 3)


@njit(cache=True, error_model="numpy", inline="always")
def task_model(n, out_n, JXs, DJ, LU, piv, col, Ji, tmp, meas):
    """D = J_X^-T M J_X^-1, C = J_X^-T (Cq - M J_X^-1 dJ_X) J_X^-1, G = J_X^-T g (eq. 4) of the nominal plant's
    kernel output ``out_n`` (level 2) with J_X = ``JXs`` and dJ_X = ``DJ`` (task frame), into ``meas``'s
    task-model blocks. LU, piv, col, Ji, tmp are scratch; DJ is overwritten. False if J_X is singular."""
    # D = J^-T M J^-1, C = J^-T (Cq - M J^-1 dJ) J^-1, G = J^-T g                 eq. (4)
    if not lu(n, JXs, 0, LU, piv):
        return False
    for c in range(n):  # Ji = J_X^-1, column by column
        for i in range(n):
            col[i] = 1.0 if i == c else 0.0
        lu_solve(n, LU, piv, col)
        for i in range(n):
            Ji[i * n + c] = col[i]
    m0 = at(OUT_M, n)
    for i in range(n):  # tmp = M Ji
        for j in range(n):
            s = 0.0
            for k2_ in range(n):
                s += out_n[m0 + i * n + k2_] * Ji[k2_ * n + j]
            tmp[i * n + j] = s
    D0 = at(M_TASK_INERTIA, n)
    for i in range(n):  # D = Ji^T (M Ji)
        for j in range(n):
            s = 0.0
            for k2_ in range(n):
                s += Ji[k2_ * n + i] * tmp[k2_ * n + j]
            meas[D0 + i * n + j] = s
    # Q = Cq Ji - (M Ji)(dJ_X Ji); C = Ji^T Q
    cq0 = at(OUT_CQ, n)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k2_ in range(n):
                s += DJ[i * n + k2_] * Ji[k2_ * n + j]
            LU[i * n + j] = s  # dJ_X Ji (LU is free now)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k2_ in range(n):
                s += out_n[cq0 + i * n + k2_] * Ji[k2_ * n + j]
            e = 0.0
            for k2_ in range(n):
                e += tmp[i * n + k2_] * LU[k2_ * n + j]
            DJ[i * n + j] = s - e  # Q (DJ is free now)
    C0 = at(M_TASK_CORIOLIS, n)
    G0 = at(M_TASK_GRAVITY, n)
    g0 = at(OUT_G, n)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k2_ in range(n):
                s += Ji[k2_ * n + i] * DJ[k2_ * n + j]
            meas[C0 + i * n + j] = s
        s = 0.0
        for k2_ in range(n):
            s += Ji[k2_ * n + i] * out_n[g0 + k2_]
        meas[G0 + i] = s
    return True
