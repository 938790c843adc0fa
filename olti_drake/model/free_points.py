"""Position model of free points: the targets of paper 001's self-calibrating multilateration (§2.3, Eq. 2-6),
in D = 2 dimensions (the paper's table) or D = 3 (the machine tool in 3D, formats.md).

The model layer of 001 (no solver here):

* :class:`FreePoints` -- N_i target positions p_i ∈ R^D, each a free parameter (001 Eq. 4: D unknowns per
  target), with their nominal positions: the commands p*_i plus the nominal offset t_m of the reflector
  mounting (``tool``) m of each target (001 §2.3: the start; the reference of the gauges of
  :mod:`olti_drake.model.gauges`). Its Jacobian is the identity, given in the sparse conventions of the
  serial model (:class:`olti_drake.model.serial.PositionJacobian`: rows x, y (, z) of point 0, then point 1,
  ...; :meth:`FreePointJacobian.contract` for distance rows) and row-compressed, batched
  (:meth:`FreePoints.rows`) for :class:`olti_drake.model.measurements.StationDistanceMeasurement`.
* :func:`fit_tool_offsets` -- the offsets of tools 1, 2, ... relative to tool 0 from the readings, given
  stations and dead paths (001 Eq. 3 with p_i = p*_i + t_m, Gauss-Newton on t_m).

Units: mm (positions, parameters, offsets; the Jacobian mm/mm).
"""

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
import scipy.sparse as sp

#: ∂p/∂(p coordinates) of a free point in D dimensions: the identity, as the rows of
#: :func:`olti_drake.model.measurements.distance_rows_nd` take them (per coordinate c, broadcastable).
UNIT_ROWS = {D: tuple(np.eye(D)) for D in (2, 3)}


@dataclass(frozen=True, eq=False)
class FreePointJacobian:
    """∂p/∂x of M points each of which is D of the parameters: point k's coordinate c is column
    ``cols[k, c]`` (mm/mm = 1), over ``n_params`` columns."""

    cols: np.ndarray
    n_params: int

    def tocsr(self, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """The (D M, n_cols) sparse Jacobian, rows x, y (, z) of point 0, then point 1, ..., plus per-row extra
        entries (``extra_vals``/``extra_cols`` (D M, e): a measurement's own parameters, columns ≥ n_params)."""
        m, D = self.cols.shape
        cols = self.cols.reshape(D * m, 1)
        vals = np.ones((D * m, 1))
        if extra_vals is not None:
            cols, vals = np.hstack([cols, extra_cols]), np.hstack([vals, extra_vals])
        return _csr(cols, vals, n_cols or self.n_params)

    def contract(self, u, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """(M, n_cols) sparse rows u_k · ∂p_k/∂x (u (M, D)), plus per-row extra entries (a measurement's own
        parameters, columns ≥ n_params)."""
        cols, vals = self.cols, np.asarray(u, dtype=float)
        if extra_vals is not None:
            cols, vals = np.hstack([cols, extra_cols]), np.hstack([vals, extra_vals])
        return _csr(cols, vals, n_cols or self.n_params)

    def take(self, index) -> "FreePointJacobian":
        """The Jacobian of the points ``index`` (e.g. the target of every reading)."""
        return FreePointJacobian(self.cols[index], self.n_params)


def _csr(cols, vals, n_cols) -> sp.csr_matrix:
    rows, width = vals.shape
    jac = sp.csr_matrix((vals.ravel(), np.asarray(cols).ravel(), np.arange(rows + 1) * width), shape=(rows, n_cols))
    jac.sum_duplicates()
    return jac


class FreePoints:
    """N_i free target positions p_i ∈ R^D (001 Eq. 4), mm.

    Parameters x (``names``): ``p{i}_x_mm, p{i}_y_mm`` (, ``p{i}_z_mm``) for i = 0 .. N_i − 1: the position
    model is x itself, p_i = (x_{D i}, ..., x_{D i + D − 1}).

    ``commands_mm`` (N_i, D): the command positions p*_i; ``tool`` (N_i,) the reflector mounting of each
    target (default 0); ``tool_offsets_mm`` (M, D) the nominal offset of each mounting, or None (no offset: a
    2D campaign without tools). ``nominal_mm`` = p*_i + t_tool(i) is the start (001 §2.3: the targets at their
    commands) and the reference of the implausibility check and of the gauges.
    """

    #: A target estimated farther than this fraction of the span of the nominal positions from its own is
    #: absurd (a machine's errors are far smaller).
    TARGET_SPAN_FRACTION = 0.1

    def __init__(self, commands_mm, tool=None, tool_offsets_mm=None):
        self.commands_mm = np.asarray(commands_mm, dtype=float)
        n_i, D = self.commands_mm.shape
        if D not in (2, 3):
            raise ValueError(f"free points: 2 or 3 coordinates per point, got {D}")
        self.dim = D
        self.tool = np.zeros(n_i, dtype=int) if tool is None else np.asarray(tool, dtype=int)
        self.tool_offsets_mm: Optional[np.ndarray] = (None if tool_offsets_mm is None
                                                      else np.asarray(tool_offsets_mm, dtype=float).reshape(-1, D))
        self.nominal_mm = self.commands_mm + (0.0 if self.tool_offsets_mm is None else self.tool_offsets_mm[self.tool])
        self.names: Tuple[str, ...] = tuple(f"p{i}_{c}_mm" for i in range(n_i) for c in "xyz"[:D])

    @property
    def n_points(self) -> int:
        return len(self.commands_mm)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def start_vector(self) -> np.ndarray:
        """The nominal positions, flattened (p0_x, p0_y, ..., mm)."""
        return self.nominal_mm.ravel()

    def _x(self, x):
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_params,):
            raise ValueError(f"parameter vector: {x.size} values, the model has {self.n_params}")
        return x

    def positions(self, x=None) -> np.ndarray:
        """The points (N_i, D) mm at x (default the start)."""
        return (self.start_vector() if x is None else self._x(x)).reshape(-1, self.dim)

    def jacobian(self, x=None):
        """The points (N_i, D) mm and their :class:`FreePointJacobian` over ``names`` (the identity)."""
        p = self.positions(x)
        return p, FreePointJacobian(np.arange(self.n_params).reshape(-1, self.dim), self.n_params)

    def rows(self, X, points):
        """The points read, batched, row-compressed (for :func:`~olti_drake.model.measurements.distance_rows_nd`).

        Args:
            X: (T, n ≥ n_params) parameter vectors (the model's first), mm.
            points: (K,) the point of every reading.

        Returns:
            p (T, K, D) mm; cols (K, D) the parameter columns of p_points[k]; dp the D unit rows (∂p_c/∂x on
            those columns, broadcastable).
        """
        D = self.dim
        p = X[:, :D * self.n_points].reshape(len(X), self.n_points, D)[:, points]
        cols = np.column_stack([D * points + c for c in range(D)])
        return p, cols, UNIT_ROWS[D]

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values or uncertainties) in result.json's keys: ``targets_mm`` (N_i, D)."""
        return {"targets_mm": np.asarray(v, dtype=float).reshape(-1, self.dim).tolist()}

    def implausible(self, x) -> list:
        """Targets more than :attr:`TARGET_SPAN_FRACTION` of the span of the nominal positions off their own,
        one phrase each (empty: plausible)."""
        c = self.nominal_mm
        span = max(float(np.ptp(c, axis=0).max()), 1e-9)
        off = np.hypot.reduce(self.positions(x) - c, axis=1)
        if off.max() > self.TARGET_SPAN_FRACTION * span:
            i = int(np.argmax(off))
            return [f"target {i} is estimated {off[i]:.6g} mm from its command, over "
                    f"{self.TARGET_SPAN_FRACTION:g} x the command span {span:g} mm"]
        return []


def fit_tool_offsets(commands_mm, tools, target, station, readings_mm, stations_mm, dead_paths_mm,
                     n_tools: int) -> np.ndarray:
    """The offsets t_m (M, D) mm of tools m = 1 .. M − 1 relative to tool 0 (t_0 = 0) from the readings.

    With the stations P_j and dead paths L0_j given (e.g. fitted to tool 0's targets at their commands),
    each tool's common offset solves 001 Eq. (3) with p_i = p*_i + t_m, ΔL = ‖p*_i + t_m − P_j‖ − L0_j, over
    that tool's readings by Gauss-Newton (≤ 30 steps, to 1e-10 mm). ``commands_mm`` (N_i, D), ``tools``
    (N_i,) per target; ``target``, ``station``, ``readings_mm`` (K,) per reading. A tool without readings
    keeps t_m = 0.
    """
    c_all = np.asarray(commands_mm, dtype=float)
    P, L0 = np.asarray(stations_mm, dtype=float), np.asarray(dead_paths_mm, dtype=float)
    t = np.zeros((n_tools, c_all.shape[1]))
    for m in range(1, n_tools):
        sel = tools[target] == m
        if not sel.any():
            continue
        c, j, reading = c_all[target[sel]], station[sel], readings_mm[sel]
        for _ in range(30):
            diff = c + t[m] - P[j]
            dist = np.hypot.reduce(diff, axis=1)
            step = np.linalg.lstsq(diff / dist[:, None], -(dist - L0[j] - reading), rcond=None)[0]
            t[m] += step
            if np.max(np.abs(step)) < 1e-10:
                break
    return t
