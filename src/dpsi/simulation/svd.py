"""Reverse-mode derivative of the 3×3 singular value decomposition.

Taichi's ``ti.svd`` is not differentiable in float64, so the simulator runs it in a kernel of its
own and back-propagates through it with this formula (Townsend, "Differentiating the singular value
decomposition", 2016), written in the numerically safer split form
    1/(s_j² − s_i²)·(a s_j + b s_i) = (a+b)/(2(s_j − s_i)) + (a−b)/(2(s_j + s_i)),
with the first denominator kept away from zero when two singular values coincide.
"""

import taichi as ti

MIN_GAP = 1e-9
"""Smallest |s_j − s_i| used in the derivative (dimensionless stretch)."""


@ti.func
def away_from_zero(d):
    return ti.select(d >= 0.0, ti.max(d, MIN_GAP), ti.min(d, -MIN_GAP))


@ti.func
def svd_backward(u, s, v, grad_u, grad_s, grad_v):
    """dL/dF for F = U diag(s) Vᵀ, given dL/dU, dL/ds and dL/dV."""
    j_mat = u.transpose() @ grad_u
    k_mat = v.transpose() @ grad_v
    m = ti.Matrix.zero(ti.f64, 3, 3)
    for i, j in ti.static(ti.ndrange(3, 3)):
        if ti.static(i == j):
            m[i, i] = grad_s[i]
        else:
            a = j_mat[i, j] - j_mat[j, i]
            b = k_mat[i, j] - k_mat[j, i]
            m[i, j] = 0.5 * (a + b) / away_from_zero(s[j] - s[i]) + 0.5 * (a - b) / away_from_zero(s[j] + s[i])
    return u @ m @ v.transpose()
