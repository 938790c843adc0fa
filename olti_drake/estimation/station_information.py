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

When the readings' standard uncertainties differ (a budget whose terms grow with the distance, 001 Table 4)
and the estimator is the *unweighted* least squares (as the multilateration's), its covariance is the
sandwich cov = Z K⁻¹ Zᵀ M Z K⁻¹ Zᵀ with K = Zᵀ S₀ Z, S₀ = Ĵᵀ Ĵ and M = Ĵᵀ diag(u_k²) Ĵ, Ĵ the reading
rows with the station's own unknowns projected out: S₀ and M are both sums over the stations
(:class:`Sandwich`, :func:`station_sandwich`), so the layout's cost still needs each station once.
"""

from dataclasses import dataclass

import numpy as np

from olti_drake.model.propagation import predicted_variance


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


@dataclass
class Sandwich:
    """The two additive parts of an unweighted estimator's covariance (module docstring): S₀ (n, n) 1 and
    M (n, n) mm² per mm² of θ. Sums like a matrix (``sum(blocks)`` starts at 0)."""

    S: np.ndarray
    M: np.ndarray

    def __add__(self, other):
        if isinstance(other, (int, float)) and other == 0:
            return self
        return Sandwich(self.S + other.S, self.M + other.M)

    __radd__ = __add__


def _project_out_station(J_theta, unit_mm) -> np.ndarray:
    """Ĵ = (I − J_s (J_sᵀJ_s)⁻¹ J_sᵀ) J_θ, dense (K, n): the rows with the station's (P, d0) projected out."""
    Jm = J_theta.toarray() if hasattr(J_theta, "toarray") else np.asarray(J_theta, float)
    Js = np.column_stack([-np.asarray(unit_mm, float), -np.ones(len(Jm))])
    return Jm - Js @ np.linalg.solve(Js.T @ Js, Js.T @ Jm)


def station_sandwich(J_theta, unit_mm, u_reading_mm) -> Sandwich:
    """(S₀, M) of one station for the unweighted estimator: rows ``J_theta`` (K, n), beam directions
    ``unit_mm`` (K, 3), the readings' standard uncertainties ``u_reading_mm`` (K,) mm."""
    Jh = _project_out_station(J_theta, unit_mm)
    u = np.asarray(u_reading_mm, float)
    return Sandwich(Jh.T @ Jh, (Jh * u[:, None] ** 2).T @ Jh)


def predicted_u(S, Z, GZ, dim: int = 3) -> np.ndarray:
    """u (mm, k = 1) of every predicted point for the information S (n, n): ``Z`` (n, r) the gauge's null
    basis, ``GZ`` (dim·K, r) the points' Jacobian times Z; the root of the trace of each point's dim × dim
    covariance block. ``S`` may be a :class:`Sandwich` (the unweighted estimator's covariance). All inf
    when Zᵀ S Z is singular (a parameter the layout does not see)."""
    sandwich = isinstance(S, Sandwich)
    K = Z.T @ (S.S if sandwich else S) @ Z
    lam, V = np.linalg.eigh(0.5 * (K + K.T))
    if lam[0] <= 1e-12 * max(lam[-1], 0.0) or lam[-1] <= 0:
        return np.full(len(GZ) // dim, np.inf)
    if sandwich:  # u² = diag(G Z K⁻¹ (Zᵀ M Z) K⁻¹ Zᵀ Gᵀ)
        u2 = predicted_variance((GZ @ V / lam) @ V.T, Z.T @ S.M @ Z, dim=dim)
    else:  # u² = diag(G Z K⁻¹ Zᵀ Gᵀ), K⁻¹ = (V/√λ)(V/√λ)ᵀ
        u2 = predicted_variance(GZ, factor=V / np.sqrt(lam), dim=dim)
    return np.sqrt(u2.sum(axis=1))
