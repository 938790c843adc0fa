"""The smoothness prior's weight from the data: restricted maximum likelihood (issue 23, item 2).

A map model (000 Eq. (6)–(9): node values per approach direction) is given the roughness prior
½ λ ‖R x‖² beside the data cost ½ Σ w r² (R: divided second differences along each map's grid, both
branches and the backlash, :meth:`olti_drake.model.errormap.ErrorMap.roughness`). Read as a Bayesian
model -- readings of variance σ², the maps' roughness Gaussian with variance σ²/λ -- the weight is chosen
where the readings are most probable (restricted, i.e. marginal, likelihood: Patterson & Thompson 1971;
Wahba 1985): the roughness the readings show. A node barely reached by the readings then follows its
neighbours instead of one reading's noise, and the posterior covariance σ² (K + λP)⁻¹ the fit states covers
the map's errors between its nodes. (Measured on random-pose six-axis campaigns, issue 23: generalized
cross-validation chose weights 10-40 x lighter -- readings of one pose share its model error -- whose u
over-stated the errors 2-5 x.)

The fit is nonlinear; the likelihood is evaluated on its linearization at a solution x̂: with K = JᵀWJ + Q
(the data's Gauss-Newton matrix plus the program's other quadratic costs) and P = RᵀR, within the program's
linear equalities. One generalized eigen-decomposition K v = μ (K + cP) v makes every λ a diagonal
evaluation (O(n) per λ), so a dense log-grid of weights is scanned exactly;
:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.fit` refits at the chosen weight and scans
again there until the choice settles.

Units: residuals in mm, λ in mm² per (deg/deg²)²·deg -- the ratio of the data cost's units to the
roughness's; it is stated so that ``--smoothing VALUE`` reproduces a choice.
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg

#: The log-grid of weights scanned, relative to c = tr K / tr P (the weight at which prior and data weigh
#: alike on average): 10^-12 .. 10^4 in steps of 0.05 decade.
GRID_DECADES = (-12.0, 4.0)
GRID_STEP_DECADES = 0.05


@dataclass
class SmoothingChoice:
    """A scanned weight: ``weight`` λ, ``score`` (−2 log of the restricted likelihood, up to a constant; NaN for
    a given weight), ``effective_parameters`` tr A(λ) (the parameters the readings determine), ``rss`` (mm²,
    weighted), ``readings`` m; ``at_edge`` when the choice lies at an end of the scanned grid; ``method``."""

    weight: float
    score: float
    effective_parameters: float
    rss: float
    readings: int
    at_edge: bool = False
    method: str = ""


def _reduced(K, P, A_eq):
    """(Ns, c): δ = Ns y spans the steps within A δ = 0, columns scaled by √diag(K + cP); c = tr K / tr P."""
    n = K.shape[0]
    trP = float(np.trace(P))
    c = float(np.trace(K)) / trP if trP > 0 else 1.0
    s = np.sqrt(np.maximum(np.diag(K) + c * np.diag(P), 0.0))
    s = np.where(s > 0, s, 1.0)
    N = _null_space(A_eq / s if A_eq.size else A_eq, n)
    return N / s[:, None], c


def _null_space(A, n):
    if not A.size:
        return np.eye(n)
    u, s, vt = np.linalg.svd(A)
    rank = int(np.sum(s > 1e-12 * max(s.max(), 1e-300)))
    return vt[rank:].T


def effective_parameters(H_data, H_total, A_eq) -> float:
    """tr A = tr(H_total⁻¹ H_data) within the linear equalities: the parameters the readings determine (the
    residual variance divides by the readings less them: m − tr A)."""
    Ns, _ = _reduced(H_total, np.zeros_like(H_total), A_eq)
    Ht, Hd = Ns.T @ H_total @ Ns, Ns.T @ H_data @ Ns
    return float(np.trace(scipy.linalg.solve(Ht, Hd, assume_a="pos")))


def _generalized(A, B):
    """eigh(A, B) with μ clipped to [0, 1]; B nudged to positive definite if rounding made it fail."""
    try:
        mu, V = scipy.linalg.eigh(A, B)
    except np.linalg.LinAlgError:
        mu, V = scipy.linalg.eigh(A, B + 1e-12 * np.trace(B) / len(B) * np.eye(len(B)))
    return np.clip(mu, 0.0, 1.0), V


def _variance_term(F: float, dof: int, floor: float) -> float:
    """−2 log L's σ² part at its best σ² ≥ ``floor``: dof log σ² + F/σ², σ² = max(F/dof, floor)."""
    dof = max(dof, 1)
    s2 = max(F / dof, floor)
    return dof * np.log(s2) + F / s2


def reml_scan(H_data, Q_other, P, g, x, A_eq, rss0: float, m: int, g_data=None, other0: float = 0.0,
              floor: float = 0.0):
    """The :class:`SmoothingChoice` of greatest restricted likelihood on the linearization at x (module doc):
    −2 log L(λ) = (m − p₀) log σ²(λ) + F(λ)/σ²(λ) + log det(K + λP) − log det₊(λP) + const, F(λ) the penalized
    cost (twice the program's cost) at its minimum, p₀ the unknowns the prior leaves free, σ²(λ) the reading
    variance at its best: F/(m − p₀), but not below ``floor`` (mm², the readings' stated variance). Without the
    floor the likelihood is flat wherever the maps can run through every reading (fewer readings than map
    values: F → 0 as λ → 0, and with it σ²), and the scan would end at the interpolating weight -- a fit with
    no residual and no u; the stated reading variance makes interpolation improbable there.

    ``H_data`` (n, n) = JᵀWJ; ``Q_other`` (n, n) or None: the Hessian of the program's other quadratic costs;
    ``P`` (n, n) = RᵀR; ``g`` (n,) the gradient of the data cost and the other costs at x (``g_data``: of the
    data cost alone, default ``g``); ``A_eq`` (k, n) the linear equalities (steps stay within them); ``rss0`` =
    Σ w r² at x, ``other0`` twice the other costs' value there; ``m`` readings (residual rows)."""
    K = H_data if Q_other is None else H_data + Q_other
    Ns, c = _reduced(K, P, A_eq)
    Kr, Pr = Ns.T @ K @ Ns, Ns.T @ P @ Ns
    mu, V = _generalized(Kr, Kr + c * Pr)  # VᵀKrV = diag(μ), Vᵀ(Kr + cPr)V = I: Kr + λPr ~ diag(μ + t(1 − μ))
    penalized = mu < 1.0 - 1e-9
    p0 = int(np.sum(~penalized))
    # The data's share VᵀHrV: diag(μ) itself without other quadratic costs (no n³ products then).
    Md = None if Q_other is None else V.T @ (Ns.T @ H_data @ Ns) @ V
    md = mu if Md is None else np.diag(Md).copy()
    a, b = V.T @ (Ns.T @ g), V.T @ (Ns.T @ (P @ x))
    ad = a if g_data is None else V.T @ (Ns.T @ g_data)
    xPx = float(x @ P @ x)
    best = None
    for e in np.arange(GRID_DECADES[0], GRID_DECADES[1] + 1e-9, GRID_STEP_DECADES):
        t = 10.0 ** e
        lam = c * t
        d = mu + t * (1.0 - mu)
        F = rss0 + other0 + lam * xPx - float(np.sum((a + lam * b) ** 2 / d))
        if not F > 0:
            continue
        score = (_variance_term(F, m - p0, floor) + float(np.sum(np.log(d)))
                 - float(np.sum(np.log(t * (1.0 - mu[penalized])))))
        if best is None or score < best[0]:
            coef = -(a + lam * b) / d
            quad = float(md @ coef ** 2) if Md is None else float(coef @ (Md @ coef))
            rss = rss0 + 2.0 * float(ad @ coef) + quad  # the data's own, at x + δ(λ)
            best = (score, lam, float(np.sum(md / d)), rss, e)
    if best is None:
        raise np.linalg.LinAlgError("the smoothness weight's likelihood is nowhere finite")
    score, lam, tr, rss, e = best
    edge = e <= GRID_DECADES[0] + 1e-9 or e >= GRID_DECADES[1] - 1e-9
    return SmoothingChoice(float(lam), float(score), tr, float(max(rss, 0.0)), int(m), bool(edge),
                           method="restricted maximum likelihood")


@dataclass
class GroupWeights:
    """Per-group smoothness weights (:func:`group_weights`): ``weights`` {group: λ_g}; ``effective`` {group: the
    parameters of the group its readings determine at the common weight}."""

    weights: dict
    effective: dict


#: A group whose readings determine fewer of its parameters than this keeps the common weight: its own roughness
#: is not seen (0/0).
GROUP_SEEN_DOF = 0.5
#: How the per-group weights are chosen, as a result states it.
GROUP_RULE = "its weight by one restricted-likelihood step from the common one, never above it"


def group_weights(H_data, Q_other, R_groups: dict, g, x, A_eq, rss0: float, m: int, cap: float, other0: float = 0.0,
                  floor: float = 0.0) -> GroupWeights:
    """One smoothness weight per group of roughness rows -- each error motion's map its own prior variance σ²/λ_g,
    for the u (:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram._group_misfit`): the roughness a map
    shows at the fit of the common weight ``cap`` (:func:`reml_scan`'s), by one Fellner-Schall step of the
    restricted likelihood from it (Wood & Fasiolo 2017, Biometrics 73(4)), on the linearization at x as
    :func:`reml_scan`: λ_g = σ² (r_g − λ tr(H⁻¹P_g)) / ‖R_g β̂‖², H = K + λP, β̂ the solution at the common weight
    λ, r_g the rank of P_g = R_gᵀR_g within the equalities, σ² the reading variance (F / (m − p₀), not below
    ``floor``) -- clipped to λ.

    Why one step and not the fixed point: a map its readings determine by a few parameters, given a lighter prior,
    fits more of the readings' noise and shows itself rougher still; on R-test campaigns the fixed point took one
    radial motion to 1/400 of the common weight from 3 parameters and every u with it 10 x beyond the errors.
    Why never above λ: a thin campaign cannot show a map smoother than the common prior -- its roughness is unread,
    not absent (measured: the common weight over-stated 8-12 x how smooth the angular motions of A were, and the
    maps' u missed them). A group whose readings determine fewer than :data:`GROUP_SEEN_DOF` of its parameters
    keeps λ.

    ``R_groups`` {group: R_g (rows, n) sparse or dense} over all variables; the rest as :func:`reml_scan`."""
    K = H_data if Q_other is None else H_data + Q_other
    names = list(R_groups)
    R = [_dense(R_groups[k]) for k in names]
    Ns, _ = _reduced(K, sum(r.T @ r for r in R), A_eq)
    B = [r @ Ns for r in R]  # R_g within the equalities: P_g,r = B_gᵀB_g
    Bz = [r @ x for r in R]
    p0 = Ns.shape[1] - np.linalg.matrix_rank(np.vstack(B))
    H = Ns.T @ K @ Ns + cap * sum(b.T @ b for b in B)
    c = scipy.linalg.cho_factor(H)
    rhs = Ns.T @ g + cap * sum(b.T @ bz for b, bz in zip(B, Bz))
    y = -scipy.linalg.cho_solve(c, rhs)
    F = rss0 + other0 + cap * sum(float(bz @ bz) for bz in Bz) + float(rhs @ y)
    s2 = max(F / max(m - p0, 1), floor)
    weights, effective = {}, {}
    for k, b, bz in zip(names, B, Bz):
        rank = np.linalg.matrix_rank(b) if b.size else 0
        effective[k] = float(rank - cap * np.sum(b * scipy.linalg.cho_solve(c, b.T).T))
        rough = float(np.sum((bz + b @ y) ** 2))
        seen = effective[k] >= GROUP_SEEN_DOF and rough > 0
        weights[k] = float(min(s2 * effective[k] / rough, cap)) if seen else float(cap)
    return GroupWeights(weights, effective)


def _dense(R):
    return R.toarray() if hasattr(R, "toarray") else np.asarray(R, float)
