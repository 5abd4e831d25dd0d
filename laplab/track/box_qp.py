"""A small sparse box-constrained quadratic program solver (the race line's inner step).

``solve_box_qp`` minimises ``0.5 x'Hx + g'x`` subject to ``lower <= x <= upper`` by a Mehrotra
predictor-corrector interior-point method on scipy's sparse LU. It knows nothing of tracks:
:mod:`laplab.track.raceline` calls it for every Gauss-Newton and trust-region step.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu


def solve_box_qp(hessian: sp.spmatrix, gradient: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 tolerance: float = 1e-9, max_iterations: int = 80) -> np.ndarray:
    """Minimise ``0.5 x'Hx + g'x`` subject to ``lower <= x <= upper`` (all (n,), H sparse (n, n) SPD).

    Mehrotra predictor-corrector interior point; each iteration factorises ``H + diag`` once (sparse LU)
    and solves twice. Needs ``lower < upper`` everywhere.
    """
    n = gradient.shape[0]
    hessian = sp.csc_matrix(hessian + sp.identity(n, format="csc") * 0.0)  # diagonal stored explicitly
    hessian.sort_indices()
    rows = np.repeat(np.arange(n), np.diff(hessian.indptr))  # column of each stored entry (CSC)
    diagonal_at = np.flatnonzero(hessian.indices == rows)
    x = 0.5 * (lower + upper)
    scale = max(1.0, float(np.abs(hessian @ x + gradient).max()))
    z_low, z_up = np.full(n, scale), np.full(n, scale)
    for _ in range(max_iterations):
        s_low, s_up = x - lower, upper - x
        residual = hessian @ x + gradient - z_low + z_up
        mu = (s_low @ z_low + s_up @ z_up) / (2 * n)
        if np.abs(residual).max() <= tolerance * scale and mu <= tolerance * scale * 1e-3:
            break
        data = hessian.data.copy()
        data[diagonal_at] += z_low / s_low + z_up / s_up
        factor = splu(sp.csc_matrix((data, hessian.indices, hessian.indptr), shape=(n, n)))

        def direction(r_low, r_up):
            dx = factor.solve(-residual + r_low / s_low - r_up / s_up)
            return dx, (r_low - z_low * dx) / s_low, (r_up + z_up * dx) / s_up

        def step_length(dx, dz_low, dz_up):
            ratios = [1.0]
            for value, delta in ((s_low, dx), (s_up, -dx), (z_low, dz_low), (z_up, dz_up)):
                shrinking = delta < 0
                if shrinking.any():
                    ratios.append(float((-value[shrinking] / delta[shrinking]).min()))
            return min(ratios)

        dx_a, dzl_a, dzu_a = direction(-s_low * z_low, -s_up * z_up)
        t_a = step_length(dx_a, dzl_a, dzu_a)
        mu_a = ((s_low + t_a * dx_a) @ (z_low + t_a * dzl_a) + (s_up - t_a * dx_a) @ (z_up + t_a * dzu_a)) / (2 * n)
        sigma_mu = (mu_a / mu) ** 3 * mu
        dx, dzl, dzu = direction(sigma_mu - s_low * z_low - dx_a * dzl_a, sigma_mu - s_up * z_up + dx_a * dzu_a)
        t = min(1.0, 0.99 * step_length(dx, dzl, dzu))
        x, z_low, z_up = x + t * dx, z_low + t * dzl, z_up + t * dzu
    return x
