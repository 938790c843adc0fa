"""The information one distance-measuring station gives on a model, its own unknowns eliminated, and the
predicted-point uncertainty of a layout -- shared by the station-layout designs (robots:
:mod:`olti_drake.estimation.serial_design`; machine tools: :mod:`olti_drake.estimation.machine_design`).

A station at P with dead path d0 reads d_k = ‖p_k(θ) − P‖ − d0 (000 Eq. (10), 001 Eq. (3) in 3D). With the
rows of the reading Jacobian on the model parameters J_θ and on the station's own unknowns J_s = [−u_k, −1]
(u_k the unit beam direction), each row divided by its reading's standard uncertainty, eliminating (P, d0)
by the Schur complement leaves

    S = J_θᵀJ_θ − J_θᵀJ_s (J_sᵀJ_s)⁻¹ J_sᵀJ_θ      (information on θ, 1/mm² for θ in mm),

and because no two stations share unknowns the information of a layout is the *sum* of its stations'.
With Z a basis of the null space of the gauge constraints on θ, cov θ = Z (Zᵀ S Z)⁻¹ Zᵀ (JCGM 100, the
constrained least squares' linear propagation); a predicted point p = G θ has u = sqrt(trace(G cov Gᵀ)).
"""

import numpy as np


def station_information(J_theta, unit_mm, weights) -> np.ndarray:
    """S (n, n) of one station (module docstring): ``J_theta`` (K, n) rows ∂d_k/∂θ (dense or scipy
    sparse), ``unit_mm`` (K, 3) unit beam directions p_k − P, ``weights`` (K,) = 1/u_k (1/mm)."""
    w = np.asarray(weights, float)
    Jm = J_theta.multiply(w[:, None]).tocsr() if hasattr(J_theta, "multiply") else np.asarray(J_theta) * w[:, None]
    Js = np.column_stack([-np.asarray(unit_mm, float), -np.ones(len(w))]) * w[:, None]
    A = Jm.T @ Jm
    A = A.toarray() if hasattr(A, "toarray") else np.asarray(A)
    B = np.asarray(Jm.T @ Js)
    return A - B @ np.linalg.solve(Js.T @ Js, B.T)


def predicted_u(S, Z, GZ, dim: int = 3) -> np.ndarray:
    """u (mm, k = 1) of every predicted point for the information S (n, n): ``Z`` (n, r) the gauge's null
    basis, ``GZ`` (dim·K, r) the points' Jacobian times Z; the root of the trace of each point's dim × dim
    covariance block. All inf when Zᵀ S Z is singular (a parameter the layout does not see)."""
    M = Z.T @ S @ Z
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    if lam[0] <= 1e-12 * max(lam[-1], 0.0) or lam[-1] <= 0:
        return np.full(len(GZ) // dim, np.inf)
    w = (GZ @ V) / np.sqrt(lam)  # u² = Σ (G Z V)² / λ per row
    return np.sqrt(np.sum(w ** 2, axis=1).reshape(-1, dim).sum(axis=1))
