"""Bidirectional positioning statistics of a rotary axis in the manner of ISO 230-2, from an error map.

ISO 230-2:2014 ("Determination of accuracy and repeatability of positioning of numerically controlled
axes", clause 3, terms and definitions) evaluates an axis from *repeated* bidirectional runs to target
positions P_i. Here the target positions are the nodes θ*_i of an identified bidirectional error map
(paper 000, Eq. 6-9) and the "mean unidirectional positional deviations" are the node values of the
model, Δθ(θ*_i, ±1) of Eq. (7) of 000:

=========================  =============================================  ==================================
symbol                     ISO 230-2 term                                  from the error map
=========================  =============================================  ==================================
x̄↑_i, x̄↓_i              mean unidirectional positional deviation at a   ``forward_deg[i]``,
                           position                                        ``reverse_deg[i]``
x̄_i                       mean bidirectional positional deviation at a    (x̄↑_i + x̄↓_i) / 2
                           position
B_i                        reversal value at a position                    x̄↑_i − x̄↓_i
B                          reversal value of an axis                       the B_i of largest |B_i|, sign kept
B̄                         mean reversal value of an axis                  mean_i B_i
E↑, E↓                    unidirectional systematic positional deviation  max_i x̄↑_i − min_i x̄↑_i (and ↓)
                           of an axis
E                          bidirectional systematic positional deviation   max(x̄↑, x̄↓) − min(x̄↑, x̄↓)
                           of an axis                                      over all nodes and both directions
M                          range of the mean bidirectional positional      max_i x̄_i − min_i x̄_i
                           deviation of an axis
=========================  =============================================  ==================================

These are **systematic** statistics of the identified model. The repeatability terms of ISO 230-2
(s_i, R↑, R↓, R) and the accuracies (A↑, A↓, A), which contain 2 s_i, need the scatter of repeated runs
at each target; one identified map holds none, so they are reported as not available
(:data:`NOT_AVAILABLE`) and never guessed.

Gauge: a rotation of the whole frame about J1 is unobservable from distances (000 §3.2, formats.md), so
the J1 map is known up to a constant. Every statistic above except the node values x̄↑_i, x̄↓_i, x̄_i
is a *difference* of node values and does not depend on that constant.

Uncertainty (JCGM 100, first order): every statistic is a linear combination g·v of the node values
v = [x̄↑_0..x̄↑_{N-1}, x̄↓_0..x̄↓_{N-1}] (deg) once the nodes that attain the max/min are fixed; for
B, E↑, E↓, E and M the uncertainty given is that of **the arg-max/arg-min combination** at the
estimate, u² = g C gᵀ. This ignores that a different node may attain the extreme under the
uncertainty; where the runner-up lies within 2 u of the extreme (``ambiguous``), the estimate of the
extreme is biased away from zero (a max of noisy values) and its u is optimistic. C is the node
covariance when known (linear propagation through the identification, correlations included), else
diag(u²) -- independence, which for the strongly positively correlated forward/reverse values of an
identified map overstates u(B_i) and understates u(x̄_i).

Units: degrees in and out; :func:`to_arcsec` and :data:`MDEG` for display.
"""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from olti_drake.model.propagation import predicted_std

#: Degrees to arc-seconds.
ARCSEC_PER_DEG = 3600.0
#: Degrees to millidegrees.
MDEG = 1e3
#: The ISO 230-2 quantities that need repeated runs (not derivable from one identified map).
NOT_AVAILABLE = {
    "R": "Bidirectional positioning repeatability R (ISO 230-2) needs the estimator s_i of the unidirectional "
         "repeatability at every target from repeated runs (ISO 230-2 asks for 5 approaches per direction); one "
         "identified error map has no run-to-run scatter.",
    "R_forward": "Unidirectional repeatability R↑: as R.",
    "R_reverse": "Unidirectional repeatability R↓: as R.",
    "A": "Accuracy A, A↑, A↓ contain 2 s_i (as R); their systematic part is E, E↑, E↓.",
}

#: The axis statistics, in the order of :attr:`AxisStatistics.gradients` rows.
STATISTICS = ("B", "B_mean", "E_forward", "E_reverse", "E", "M")
#: Statistics defined by a max/min over nodes (their u is that of the arg-max combination).
EXTREME = ("B", "E_forward", "E_reverse", "E", "M")


def to_arcsec(deg):
    """Degrees -> arc-seconds (1 mdeg = 3.6″)."""
    return np.asarray(deg, dtype=float) * ARCSEC_PER_DEG


@dataclass
class AxisStatistics:
    """ISO 230-2 style systematic statistics of one axis (all angles in degrees).

    Node arrays (N,) at ``positions_deg`` (the map grid θ*_i): ``forward_deg`` x̄↑_i,
    ``reverse_deg`` x̄↓_i, ``reversal_deg`` B_i = x̄↑_i − x̄↓_i, ``mean_deg`` x̄_i = (x̄↑_i + x̄↓_i)/2.
    Axis values: ``B_deg`` (reversal value of the axis: B_i at ``B_index``, the node of largest
    |B_i|, sign kept), ``B_mean_deg`` (B̄), ``E_forward_deg`` (E↑), ``E_reverse_deg`` (E↓), ``E_deg``,
    ``M_deg``. ``where`` names, per extreme statistic, the nodes that attain it: ``{"B": i,
    "E_forward": (i_max, i_min), "E": ((i, dir), (i, dir)), ...}`` with dir +1/−1.

    Uncertainties (k = 1, deg) when given node uncertainties: ``u_forward_deg`` ... ``u_mean_deg``
    (N,) and ``u`` {statistic: u}; ``ambiguous`` {statistic: bool} -- True where the runner-up of a
    max/min lies within 2 u of it (the first-order u is then optimistic, the estimate biased);
    ``correlated``: whether a node covariance (True) or independence (False) was used.
    ``gradients`` (6, 2N): dg/dv of each statistic (:data:`STATISTICS` order) in the node vector
    [forward..., reverse...] -- the linearization the u come from.
    """

    axis: str
    positions_deg: np.ndarray
    forward_deg: np.ndarray
    reverse_deg: np.ndarray
    reversal_deg: np.ndarray
    mean_deg: np.ndarray
    B_deg: float
    B_index: int
    B_mean_deg: float
    E_forward_deg: float
    E_reverse_deg: float
    E_deg: float
    M_deg: float
    where: dict
    gradients: np.ndarray
    u_forward_deg: Optional[np.ndarray] = None
    u_reverse_deg: Optional[np.ndarray] = None
    u_reversal_deg: Optional[np.ndarray] = None
    u_mean_deg: Optional[np.ndarray] = None
    u: dict = field(default_factory=dict)
    ambiguous: dict = field(default_factory=dict)
    correlated: Optional[bool] = None

    @property
    def n_nodes(self) -> int:
        return self.positions_deg.size

    def value(self, name: str) -> float:
        """An axis statistic by its :data:`STATISTICS` name, deg."""
        return float(getattr(self, f"{name}_deg"))

    def to_dict(self) -> dict:
        """Plain JSON-able dict, degrees (the report's ``iso230.json``)."""
        def arr(a):
            return None if a is None else np.asarray(a, dtype=float).tolist()

        out = {"axis": self.axis, "unit": "deg",
               "nodes": {"positions_deg": arr(self.positions_deg), "forward_deg": arr(self.forward_deg),
                         "reverse_deg": arr(self.reverse_deg), "reversal_deg": arr(self.reversal_deg),
                         "mean_deg": arr(self.mean_deg)},
               "B_index": int(self.B_index),
               "where": {k: _plain(v) for k, v in self.where.items()}}
        out.update({f"{s}_deg": self.value(s) for s in STATISTICS})
        if self.u:
            out["nodes"].update({"u_forward_deg": arr(self.u_forward_deg), "u_reverse_deg": arr(self.u_reverse_deg),
                                 "u_reversal_deg": arr(self.u_reversal_deg), "u_mean_deg": arr(self.u_mean_deg)})
            out["u_deg"] = {k: float(v) for k, v in self.u.items()}
            out["ambiguous"] = {k: bool(v) for k, v in self.ambiguous.items()}
            out["correlated"] = bool(self.correlated)
        out["not_available"] = dict(NOT_AVAILABLE)
        return out


def _plain(v):
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    return int(v) if isinstance(v, (np.integer, int)) else float(v)


def _gap_ambiguous(values, order_desc, g_rows, C) -> bool:
    """Is the runner-up within 2 u of the extreme? ``order_desc``: candidate indices, extreme first."""
    if len(order_desc) < 2:
        return False
    a, b = order_desc[0], order_desc[1]
    gap = abs(values[a] - values[b])
    d = g_rows[a] - g_rows[b]
    u = float(predicted_std(d[None], C)[0])  # u of the gap's one row
    return bool(gap < 2.0 * u)


def axis_statistics(error_map, std=None, cov=None, axis: Optional[str] = None) -> AxisStatistics:
    """ISO 230-2 style systematic statistics of one axis from its identified map (module docstring).

    Args:
        error_map: an :class:`~olti_drake.model.errormap.ErrorMap` (or anything with ``grid_deg``,
            ``forward_deg``, ``reverse_deg``), deg -- Δθ(θ*_i, ±1) of Eq. (7) of 000 at its nodes.
        std: optional standard uncertainties (k = 1, deg) of the node values, (2N,) as
            [forward..., reverse...] or a pair (forward (N,), reverse (N,)); independence assumed.
        cov: optional covariance (2N, 2N) deg² of [forward..., reverse...] (e.g. the map block of the
            linear covariance of the identification, correlations included). Takes precedence over std.
        axis: label (default ``error_map.axis``).

    Returns:
        :class:`AxisStatistics`; with ``std`` or ``cov``, first-order standard uncertainties of every
        node quantity and statistic (for max/min: of the arg-max combination, see module docstring).
    """
    g = np.asarray(error_map.grid_deg, dtype=float).ravel()
    f = np.asarray(error_map.forward_deg, dtype=float).ravel()
    r = np.asarray(error_map.reverse_deg, dtype=float).ravel()
    n = g.size
    if not (f.size == n and r.size == n) or n == 0:
        raise ValueError(f"error map {axis or getattr(error_map, 'axis', '?')}: need N >= 1 nodes with N forward "
                         f"and N reverse values, got {n}, {f.size}, {r.size}")
    v = np.concatenate([f, r])
    eye = np.eye(n)
    F = np.hstack([eye, np.zeros((n, n))])      # x̄↑_i = F v
    R = np.hstack([np.zeros((n, n)), eye])      # x̄↓_i = R v
    Bi, Xi = F - R, 0.5 * (F + R)                # B_i, x̄_i
    Bv, xv = Bi @ v, Xi @ v
    V = np.vstack([F, R])                        # both directions: all 2N node values

    iB = int(np.argmax(np.abs(Bv)))
    extremes = {"E_forward": (F, f), "E_reverse": (R, r), "E": (V, v), "M": (Xi, xv)}
    where, rows = {"B": iB}, {"B": Bi[iB], "B_mean": Bi.mean(axis=0)}
    for name, (G, vals) in extremes.items():
        hi, lo = int(np.argmax(vals)), int(np.argmin(vals))
        rows[name] = G[hi] - G[lo]
        where[name] = ((hi % n, 1 if hi < n else -1), (lo % n, 1 if lo < n else -1)) if name == "E" else (hi, lo)
    grad = np.vstack([rows[s] for s in STATISTICS])
    vals = grad @ v
    out = AxisStatistics(
        axis=axis or getattr(error_map, "axis", "J?"), positions_deg=g, forward_deg=f, reverse_deg=r,
        reversal_deg=Bv, mean_deg=xv, B_deg=float(vals[0]), B_index=iB, B_mean_deg=float(vals[1]),
        E_forward_deg=float(vals[2]), E_reverse_deg=float(vals[3]), E_deg=float(vals[4]), M_deg=float(vals[5]),
        where=where, gradients=grad)
    if cov is None and std is None:
        return out

    if cov is not None:
        C = np.asarray(cov, dtype=float)
        if C.shape != (2 * n, 2 * n):
            raise ValueError(f"error map {out.axis}: node covariance must be ({2 * n}, {2 * n}), got {C.shape}")
        C = 0.5 * (C + C.T)
    else:
        s = np.concatenate([np.ravel(a) for a in std]) if isinstance(std, (tuple, list)) else np.ravel(std)
        s = np.asarray(s, dtype=float)
        if s.shape != (2 * n,):
            raise ValueError(f"error map {out.axis}: node uncertainties must have {2 * n} values "
                             f"(forward then reverse), got {s.size}")
        C = np.diag(s ** 2)

    def u_rows(G):
        return predicted_std(G, C)

    out.u_forward_deg, out.u_reverse_deg = u_rows(F), u_rows(R)
    out.u_reversal_deg, out.u_mean_deg = u_rows(Bi), u_rows(Xi)
    out.u = dict(zip(STATISTICS, u_rows(grad).tolist()))
    absB = np.abs(Bv)
    sgnB = np.sign(Bv)[:, None] * Bi  # |B_i| = sign(B_i) B_i, locally linear
    out.ambiguous = {"B": _gap_ambiguous(absB, np.argsort(-absB, kind="stable"), sgnB, C)}
    for name, (G, vals_) in extremes.items():
        out.ambiguous[name] = (_gap_ambiguous(vals_, np.argsort(-vals_, kind="stable"), G, C)
                               or _gap_ambiguous(-vals_, np.argsort(vals_, kind="stable"), -G, C))
    out.correlated = cov is not None
    return out


def map_statistics(model, std=None, cov=None) -> dict:
    """{"J1": AxisStatistics, "J2": AxisStatistics} of an error-map :class:`ScaraModel` (000 Eq. 6-9).

    ``std``: optional {axis: (2N,) node standard uncertainties, deg}; ``cov``: optional {axis: (2N, 2N)
    node covariance, deg²} (takes precedence per axis). See :func:`axis_statistics`.
    """
    if not getattr(model, "is_errormap", False):
        raise ValueError("ISO 230-2 statistics need an error-map model (model 'errormap'); a D-H model has no "
                         "bidirectional angular positioning deviation")
    std, cov = std or {}, cov or {}
    return {axis: axis_statistics(m, std=std.get(axis), cov=cov.get(axis), axis=axis)
            for axis, m in (("J1", model.map1), ("J2", model.map2))}


def node_std(uncertainty: dict, axis: str) -> np.ndarray:
    """(2N,) node standard uncertainties [forward..., reverse...] deg from a formats.md ``uncertainty`` object."""
    m = uncertainty["error_map"][axis]
    return np.concatenate([np.asarray(m["forward_deg"], dtype=float), np.asarray(m["reverse_deg"], dtype=float)])


def node_indices(names, axis: str, n: int) -> np.ndarray:
    """Indices of an axis's node values [forward..., reverse...] in a parameter-name list
    (``J1_forward_deg[0]``, ... as :class:`~olti_drake.estimation.identification.Identifier` names them)."""
    names = list(names)
    # a one-directional map (no reverse parameters): the reverse values are the forward ones, mirrored
    blocks = ("forward", "reverse") if f"{axis}_reverse_deg[0]" in names else ("forward", "forward")
    return np.array([names.index(f"{axis}_{block}_deg[{i}]") for block in blocks for i in range(n)])
