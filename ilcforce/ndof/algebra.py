"""Small dense algebra for the n-joint loop (docs/model.md#n-dof), on scratch arrays it is given (no allocation):
Cholesky for the joint inertia M, LU with partial pivoting for the task Jacobian J_X, and the nominal task-space
model of eq. (4) into the law's measurement vector. Matrices are n x n, row-major, in flat arrays.
"""

from __future__ import annotations

import math

from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import M_TASK_CORIOLIS, M_TASK_GRAVITY, M_TASK_INERTIA, at

# offsets of the plant kernel's output (ilcforce.plants.nd: its layout as (a, b, c), offset a + b n + c n^2)
OUT_P, OUT_J = (0, 0, 0), (0, 1, 0)
OUT_DJV, OUT_M, OUT_B = (0, 1, 1), (0, 2, 1), (0, 2, 2)
OUT_CQ, OUT_G, OUT_DJ = (0, 3, 2), (0, 3, 3), (0, 4, 3)


# --- small dense algebra on scratch arrays (no allocation) -----------------------------------------

@njit(cache=True, error_model="numpy", inline="always")
def cholesky(n, A, a0, L):
    """L (n x n, lower, row-major in L[0:n*n]) with L L^T = A[a0:a0 + n*n]; False if not positive definite."""
    for i in range(n):
        for j in range(i + 1):
            s = A[a0 + i * n + j]
            for k in range(j):
                s -= L[i * n + k] * L[j * n + k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i * n + i] = math.sqrt(s)
            else:
                L[i * n + j] = s / L[j * n + j]
    return True


@njit(cache=True, error_model="numpy", inline="always")
def cholesky_solve(n, L, b, x):
    """x = (L L^T)^-1 b (x may be b)."""
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i * n + k] * x[k]
        x[i] = s / L[i * n + i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k * n + i] * x[k]
        x[i] = s / L[i * n + i]


@njit(cache=True, error_model="numpy", inline="always")
def lu(n, A, a0, LU, piv):
    """LU with partial pivoting of A[a0:a0 + n*n] into LU; False if singular."""
    for i in range(n * n):
        LU[i] = A[a0 + i]
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(LU[r * n + c]) > abs(LU[p * n + c]):
                p = r
        piv[c] = p
        if LU[p * n + c] == 0.0 or not math.isfinite(LU[p * n + c]):
            return False
        if p != c:
            for j in range(n):
                LU[c * n + j], LU[p * n + j] = LU[p * n + j], LU[c * n + j]
        for r in range(c + 1, n):
            f = LU[r * n + c] / LU[c * n + c]
            LU[r * n + c] = f
            for j in range(c + 1, n):
                LU[r * n + j] -= f * LU[c * n + j]
    return True


@njit(cache=True, error_model="numpy", inline="always")
def lu_solve(n, LU, piv, x):
    """x <- A^-1 x in place."""
    for c in range(n):
        p = int(piv[c])
        if p != c:
            x[c], x[p] = x[p], x[c]
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= LU[i * n + k] * x[k]
        x[i] = s
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= LU[i * n + k] * x[k]
        x[i] = s / LU[i * n + i]


@njit(cache=True, error_model="numpy", inline="always")
def lu_solve_transposed(n, LU, piv, x):
    """x <- A^-T x in place (A = P^T L U, so A^T y = x is U^T L^T P y = x)."""
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= LU[k * n + i] * x[k]
        x[i] = s / LU[i * n + i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= LU[k * n + i] * x[k]
        x[i] = s
    for c in range(n - 1, -1, -1):
        p = int(piv[c])
        if p != c:
            x[c], x[p] = x[p], x[c]




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
