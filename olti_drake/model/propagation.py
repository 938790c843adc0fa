"""The standard uncertainty of a predicted quantity from a fit's covariance: the one implementation (issue 22).

A prediction y = f(θ) -- a point of D coordinates (mm), or a scalar such as one error-motion value (mm or
µrad) or a statistic of an identified map (deg) -- linearised at the estimate, y ≈ f(θ̂) + J (θ − θ̂), has the
covariance J C Jᵀ, C the covariance of the identified parameters θ (JCGM 100 §5.2.2, the law of propagation
of uncertainty for correlated input quantities; first order, as the linear method of 000 §5 Remark and
001 §4.4). Each predicted coordinate k has the standard uncertainty (k = 1)

    u_k = sqrt((J C Jᵀ)_kk) = sqrt(Σ_j (J C)_kj J_kj),

the row sums of (J C) ∘ J: formed a block of rows at a time, never the (M, M) product J C Jᵀ, with a sparse
J kept sparse. Its uses: the predicted-position uncertainty map of 001 Fig. 14 and of the identified error
map of 000 (its map uncertainty, Fig. 6's error bars carried to positions), the cost of the station-layout
designs (the worst or mean u over the workspace), the tool points and motion values of a volumetric result,
and the ISO 230-2 statistics of an identified map.

Pure numpy/scipy and in the model layer so that every layer may use it (``io`` may not import
``estimation``). Units: those of J times those of sqrt(C); the callers' docstrings state them.
"""

import numpy as np
import scipy.sparse as sp

#: Values of the (rows, n) block J C held at once: bounds the temporary memory on large problems.
CHUNK_VALUES = 4_000_000


def predicted_variance(J, covariance=None, *, factor=None, dim=None) -> np.ndarray:
    """diag(J C Jᵀ) (module docstring): the variance of every predicted coordinate, clipped at 0.

    ``J``: (R, n) rows ∂y_k/∂θ, dense or scipy sparse, or (M, D, n) dense (D coordinates per point).
    ``covariance``: C (n, n), or a callable that forms it (a deferred covariance,
    :func:`~olti_drake.estimation.calibration.deferred_covariance`): called once here.
    ``factor``: instead of C, L (n, r) with C = L Lᵀ (e.g. V/√λ of an eigendecomposition): the row sums of
    (J L)², never negative whatever C's condition.
    ``dim``: read the rows of a 2-D J as points of ``dim`` coordinates (row m·dim + d: coordinate d of point m).
    Returns (R,), or (M, D) for a 3-D J or with ``dim``."""
    if (covariance is None) == (factor is None):
        raise ValueError("predicted_variance needs exactly one of covariance and factor")
    shape = None
    if not sp.issparse(J):
        J = np.asarray(J, float)
        if J.ndim == 3:
            shape = J.shape[:2]
            J = J.reshape(-1, J.shape[2])
    else:
        J = J.tocsr()
    if dim is not None:
        shape = (-1, dim)
    if factor is not None:
        var = _row_sums(J, np.asarray(factor, float), squared=True)
    else:
        C = covariance() if callable(covariance) else covariance
        var = _row_sums(J, np.asarray(C, float), squared=False)
    var = np.maximum(var, 0.0)  # rounding of a near-singular C, never a negative variance
    return var if shape is None else var.reshape(shape)


def predicted_std(J, covariance=None, *, factor=None, dim=None) -> np.ndarray:
    """Standard uncertainty (k = 1) of every predicted coordinate, sqrt(diag(J C Jᵀ)): the arguments and shapes
    of :func:`predicted_variance` -- (R,) for scalar predictions, (M, D) for points."""
    return np.sqrt(predicted_variance(J, covariance, factor=factor, dim=dim))


def with_lack_of_fit(u, lack_of_fit_mm: float):
    """u (any shape, mm) with the fit's model error (mm) added in quadrature: the u of a predicted point
    coordinate or reading (:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.lack_of_fit`)."""
    return np.sqrt(np.square(u) + float(lack_of_fit_mm) ** 2)


def _row_sums(J, B, squared: bool) -> np.ndarray:
    """Σ_j (J B)_kj² (``squared``) or Σ_j (J B)_kj J_kj per row k, a block of rows at a time (CHUNK_VALUES)."""
    rows = J.shape[0]
    step = max(1, CHUNK_VALUES // max(B.shape[1], 1))
    out = np.empty(rows)
    for i in range(0, rows, step):
        Ji = J[i:i + step]
        JB = np.asarray(Ji @ B)
        if squared:
            out[i:i + step] = np.sum(JB ** 2, axis=1)
        elif sp.issparse(Ji):  # only J's nonzeros enter the sum
            out[i:i + step] = np.asarray(Ji.multiply(JB).sum(axis=1)).ravel()
        else:
            out[i:i + step] = np.sum(JB * Ji, axis=1)
    return out


def psd_sqrt(G) -> np.ndarray:
    """The symmetric square root S = V diag(√λ) Vᵀ of a positive semi-definite G (n, n) (negative rounding of λ
    taken as 0): draws S z (z ~ N(0, I)) have covariance G. Unlike V diag(√λ), which hangs on the eigenvector
    basis eigh picks inside a repeated eigenvalue (a prior's null space; rounding decides it), S is unique: the
    same G in another row order of its campaign draws the same samples."""
    G = np.asarray(G, float)
    lam, V = np.linalg.eigh((G + G.T) / 2)
    return (V * np.sqrt(np.maximum(lam, 0.0))) @ V.T
