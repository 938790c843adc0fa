"""One uncertainty of a predicted point or reading from a fit's covariance (issue 22):
:func:`olti_drake.model.propagation.predicted_std`, u = sqrt(diag(J C Jᵀ)) (JCGM 100 §5.2.2).

Checked against the explicit dense formula (dense, sparse and per-point Jacobians, a factored and a deferred
covariance, in blocks of rows), against a seeded Monte Carlo of the same linear model, and, by reading the
source with ``ast``, that no other module of the package computes diag(J C Jᵀ) on its own."""

import ast
import os

import numpy as np
import pytest
import scipy.sparse as sp

from olti_drake.model import propagation
from olti_drake.model.propagation import predicted_std, predicted_variance

PKG = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "olti_drake")
ONE_HOME = os.path.join("model", "propagation.py")


def _problem(seed=0, rows=60, n=9, density=0.3):
    """(J (rows, n) with zeros, C (n, n) SPD) in mm and mm² (seeded)."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(rows, n)) * (rng.random((rows, n)) < density)
    A = rng.normal(size=(n, n)) * 1e-3
    return J, A @ A.T + 1e-8 * np.eye(n)


def _dense_u(J, C):
    """The explicit formula: the diagonal of the whole (rows, rows) product."""
    return np.sqrt(np.diag(J @ C @ J.T))


def test_dense_sparse_and_per_point_jacobians_give_the_dense_formula():
    J, C = _problem()
    u = _dense_u(J, C)
    np.testing.assert_allclose(predicted_std(J, C), u, rtol=1e-12)
    for fmt in (sp.csr_matrix, sp.csc_matrix, sp.coo_matrix, sp.csr_array):
        np.testing.assert_allclose(predicted_std(fmt(J), C), u, rtol=1e-12)
    np.testing.assert_allclose(predicted_std(sp.csr_matrix(J), C, dim=3), u.reshape(-1, 3), rtol=1e-12)
    np.testing.assert_allclose(predicted_std(J.reshape(-1, 3, J.shape[1]), C), u.reshape(-1, 3), rtol=1e-12)
    np.testing.assert_allclose(predicted_variance(J, C), u ** 2, rtol=1e-12)


def test_factored_and_deferred_covariances_give_the_same_u():
    from olti_drake.estimation.calibration import Fit, deferred_covariance

    J, C = _problem(1)
    lam, V = np.linalg.eigh(C)
    np.testing.assert_allclose(predicted_std(J, factor=V * np.sqrt(lam)), _dense_u(J, C), rtol=1e-10)
    formed = []

    def form():  # a large fit's covariance, formed when first needed
        formed.append(1)
        return C

    fit = Fit(["a"] * len(C), np.zeros(len(C)), np.sqrt(np.diag(C)), form, np.zeros(3), 1, 1.0, "lm")
    lazy = deferred_covariance(fit)
    assert callable(lazy) and not formed
    np.testing.assert_allclose(predicted_std(sp.csr_matrix(J), lazy, dim=3), _dense_u(J, C).reshape(-1, 3),
                               rtol=1e-12)
    assert formed == [1]  # formed once
    with pytest.raises(ValueError, match="exactly one"):
        predicted_std(J)
    with pytest.raises(ValueError, match="exactly one"):
        predicted_std(J, C, factor=V)


def test_rows_are_taken_in_blocks_without_changing_u(monkeypatch):
    """Large problems: the (rows, n) block J C is formed a few rows at a time -- the same u."""
    J, C = _problem(2, rows=301)
    whole = predicted_std(sp.csr_matrix(J), C)
    monkeypatch.setattr(propagation, "CHUNK_VALUES", 2 * J.shape[1])  # two rows per block
    np.testing.assert_allclose(predicted_std(sp.csr_matrix(J), C), whole, rtol=1e-14)
    np.testing.assert_allclose(predicted_std(J, C), whole, rtol=1e-12)
    lam, V = np.linalg.eigh(C)
    np.testing.assert_allclose(predicted_std(J, factor=V * np.sqrt(lam)), whole, rtol=1e-10)


def test_a_rounding_negative_variance_is_zero_not_nan():
    J = np.array([[1.0, -1.0], [1.0, 0.0]])
    C = np.array([[1.0, 1.0], [1.0, 1.0]]) * (1 + 1e-16)  # singular along (1, -1)
    u = predicted_std(J, C - 1e-18 * np.eye(2))
    assert np.all(np.isfinite(u)) and u[0] < 1e-8


def test_the_spread_of_a_seeded_monte_carlo_of_the_linear_model():
    """θ ~ N(θ̂, C) through y = y0 + J (θ − θ̂): the sample spread of y per coordinate (T samples) agrees with
    u within 4 relative standard errors of a sample standard deviation, 1/sqrt(2(T − 1))."""
    J, C = _problem(3, rows=30, density=0.6)
    T = 40_000
    theta = np.random.default_rng(20240622).multivariate_normal(np.zeros(len(C)), C, size=T)
    spread = (theta @ J.T).std(axis=0, ddof=1).reshape(-1, 3)
    u = predicted_std(sp.csr_matrix(J), C, dim=3)
    assert np.all(np.abs(spread / u - 1) < 4 / np.sqrt(2 * (T - 1)))


# -- one implementation: no other module computes diag(J C Jᵀ) by itself ----------------------------------------
def _strip(node):
    """``node`` without np.asarray(...) / np.array(...) wrappers and ``.toarray()``: the same value."""
    while True:
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args
                and node.func.attr in ("asarray", "array", "asanyarray")):
            node = node.args[0]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and not node.args
              and node.func.attr in ("toarray", "todense")):
            node = node.func.value
        else:
            return node


def _same(a, b) -> bool:
    return ast.dump(_strip(a)) == ast.dump(_strip(b))


def _is_transpose_of(t, a) -> bool:
    return isinstance(t, ast.Attribute) and t.attr == "T" and _same(t.value, a)


def _matmul_ends(node):
    """(leftmost, rightmost) operand of a chain a @ b @ ... @ z, or None."""
    node = _strip(node)
    if not (isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult)):
        return None
    left = node.left
    while isinstance(_strip(left), ast.BinOp) and isinstance(_strip(left).op, ast.MatMult):
        left = _strip(left).left
    return left, node.right


def _left_of_matmul(node):
    ends = _matmul_ends(node)
    return None if ends is None else ends[0]


def _quadratic_forms(source: str) -> list:
    """Line numbers where ``source`` forms diag(J C Jᵀ) (or one row's d C dᵀ) itself: (J @ C) * J summed,
    J.multiply(J @ C), einsum(.., J, C, J), diag(J @ C @ J.T), d @ C @ d. A name bound once in a function stands
    for its value (``JC = J @ C; J.multiply(JC)``)."""
    tree = ast.parse(source)
    hits = []
    scopes = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))]
    for scope in [tree] + scopes:
        bound = {}
        for n in ast.walk(scope):
            if isinstance(n, ast.Assign) and len(n.targets) == 1 and isinstance(n.targets[0], ast.Name):
                bound.setdefault(n.targets[0].id, []).append(n.value)
        once = {k: v[0] for k, v in bound.items() if len(v) == 1}

        def value(node):
            node = _strip(node)
            return _strip(once.get(node.id, node)) if isinstance(node, ast.Name) else node

        for n in ast.walk(scope):
            if isinstance(n, ast.BinOp) and isinstance(n.op, ast.Mult):  # (J @ C) * J, J * (J @ C)
                for a, b in ((n.left, n.right), (n.right, n.left)):
                    left = _left_of_matmul(value(a))
                    if left is not None and _same(value(left), value(b)):
                        hits.append(n.lineno)
            elif isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute):
                f, args = n.func.attr, n.args
                if f == "multiply" and len(args) == 1:  # sparse J.multiply(J @ C)
                    left = _left_of_matmul(value(args[0]))
                    if left is not None and _same(value(left), value(n.func.value)):
                        hits.append(n.lineno)
                elif f == "einsum" and len(args) == 4 and _same(value(args[1]), value(args[3])):
                    hits.append(n.lineno)
                elif f == "diag" and len(args) == 1:  # diag(J @ C @ J.T)
                    ends = _matmul_ends(value(args[0]))
                    if ends and _is_transpose_of(ends[1], ends[0]):
                        hits.append(n.lineno)
            if isinstance(n, ast.Call) and _name(n.func) in SCALAR_CALLS:  # sqrt(d @ C @ d): one row's variance
                for arg in n.args:
                    ends = _matmul_ends(value(arg))
                    if (ends and isinstance(_strip(value(arg).left), ast.BinOp)
                            and _same(value(ends[0]), value(ends[1]))):
                        hits.append(n.lineno)
    return sorted(set(hits))


#: Calls that take a quadratic form d @ C @ d as one variance (a full B @ C @ B product is a covariance).
SCALAR_CALLS = {"float", "sqrt", "max", "maximum"}


def _name(func) -> str:
    return func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""


def _function_at(tree, line: int) -> str:
    """The innermost function holding ``line`` ('' at module level)."""
    best = (0, "")
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.lineno <= line <= n.end_lineno:
            best = max(best, (n.lineno, n.name))
    return best[1]


#: (file, function): why a diag(Z K Zᵀ) there is not the uncertainty of a prediction.
NOT_PREDICTIONS = {
    ("estimation/serial_plan.py", "plan_report"):
        "the parameters' own variances within the gauge, diag(Z (ZᵀJᵀJZ)⁺ Zᵀ): Z is the gauge's null basis",
    ("estimation/machine_design.py", "_parts"): "the design's per-station blocks (a aᵀ, a w aᵀ), no covariance",
    ("estimation/machine_design.py", "_u"):
        "the design's target variances of candidate layouts by block elimination (3 x 3 per target, the stations' "
        "Schur complement): a layout's cost, not a prediction from an identification's covariance",
    ("estimation/smoothing.py", "reml_scan"): "the roughness prior's value xᵀPx at the solution (issue 23)",
    ("estimation/serial_uncertainty.py", "_covariance_sigma"):
        "the parameters' own variances per unit σ², diag(B (JᵀJ + Q) Bᵀ): the σ² a stored covariance was formed with",
}


#: The ways the package computed it before issue 22 (the six sites, reduced): the check must see each.
_FORMER = {
    "scara": "def f(jx, jy, C):\n    return [np.sum((j @ C) * j, axis=1) for j in (jx.toarray(), jy.toarray())]\n",
    "serial": ("def f(jac, cov):\n    J = jac.tocsr()\n    JC = np.asarray(J @ cov)\n"
               "    return J.multiply(JC).sum(axis=1)\n"),
    "design": ("def f(GZ, V, lam, Z, S):\n    W = (GZ @ V / lam) @ V.T\n"
               "    return np.sum((W @ (Z.T @ S.M @ Z)) * W, axis=1)\n"),
    "motion": ("def f(basis, names, C, s):\n    for name in names:\n        B = basis(name)[:, s]\n"
               "        yield np.sqrt(np.maximum(np.sum((B @ C[s, s]) * B, axis=1), 0.0))\n"),
    "volumetric": "def f(J, C):\n    return np.einsum('mip,pq,miq->mi', J, C, J)\n",
    "iso230": "def f(G, C, d):\n    return np.einsum('ij,jk,ik->i', G, C, G), float(d @ C @ d)\n",
    "dense": "def f(J, C):\n    return np.sqrt(np.diag(J @ C @ J.T))\n",
}


@pytest.mark.parametrize("name", sorted(_FORMER))
def test_the_check_sees_every_former_way(name):
    assert _quadratic_forms(_FORMER[name]), name


def test_the_check_leaves_other_products_alone():
    other = ("def f(J, w, C, E, x):\n    A = J.T @ J\n    Jm = J.multiply(w[:, None])\n    S = E @ C @ E.T\n"
             "    return A, Jm, S, np.sum(x * x), np.einsum('ij,ij->i', J, J), C @ x - 1\n")
    assert _quadratic_forms(other) == []


def test_no_other_module_computes_the_predicted_uncertainty_itself():
    found = {}
    for dirpath, _, files in os.walk(PKG):
        for f in files:
            path = os.path.join(dirpath, f)
            if f.endswith(".py") and os.path.relpath(path, PKG) != ONE_HOME:
                with open(path, encoding="utf-8") as fh:
                    source = fh.read()
                rel = os.path.relpath(path, PKG).replace(os.sep, "/")
                tree = ast.parse(source)
                lines = [(k, _function_at(tree, k)) for k in _quadratic_forms(source)]
                lines = [hit for hit in lines if (rel, hit[1]) not in NOT_PREDICTIONS]
                if lines:
                    found[rel] = lines
    assert not found, ("diag(J C Jᵀ) computed outside olti_drake/model/propagation.py (call predicted_std): "
                       f"{found}")
