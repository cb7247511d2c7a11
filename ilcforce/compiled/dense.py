"""Small dense algebra on flat scratch arrays it is given (no allocation), for compiled loops and laws: Cholesky
(the n-joint loop's joint inertia M) and LU with partial pivoting (the task Jacobian J_X, in the loop and in
sl-adapt's n-axis law). Matrices are n x n, row-major, in flat arrays.
"""

from __future__ import annotations

import math

from ilcforce.compiled.jit import njit

__all__ = ["cholesky", "cholesky_solve", "lu", "lu_solve", "lu_solve_transposed"]


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
