"""One calibration program: a position model, a measurement, a gauge, solver options.

Paper 000 Eq. (5)/(10) (a SCARA reflector P_j with dead path d0_j) and paper 001 Eq. (3) (a machine-tool
station P_j with dead path L0_j) read the same thing: d = ‖p − P_j‖ − d0_j, mm.

* :func:`station_fit`: (P_j, d0_j) from points p taken as known (nominal kinematics, or commands) -- the
  start of the SCARA identification and of the multilateration.
* :class:`Calibration`: the least-squares program (:class:`~olti_drake.estimation.leastsquares.LeastSquaresProgram`:
  data cost on ``prog``, identifiability, robust loss, covariance, acceptance; Monte Carlo and linear
  propagation in :mod:`olti_drake.estimation.uncertainty`) over any *measurement* object that offers
  ``names``, ``start_vector()``, ``residuals(x) -> (r, sparse dr/dx)``, ``beam_lengths(x)`` and
  ``layout(v)`` -- e.g. :class:`olti_drake.model.serial.DistanceMeasurement` on an N-joint
  :class:`~olti_drake.model.serial.SerialPositionModel`, with the gauge of
  :func:`olti_drake.model.serial.find_gauge`. The SCARA :class:`~olti_drake.estimation.identification.Identifier`
  and the 2D :class:`~olti_drake.estimation.multilateration.Multilateration` are the same program with
  their residuals written in place (batched for the Monte Carlo).
"""

import numpy as np

from olti_drake.estimation.leastsquares import LeastSquaresProgram, SolverOptions


def distance_rows(p, pcols, dpx, dpy, P, d0, station, readings, station_col: int, dead_path_col: int):
    """The distance residual of both papers in 2D (000 Eq. 10, 001 Eq. 3); see :func:`distance_rows_nd`.

    ``dpx``, ``dpy``: (K, m) the position model's ∂p_x, ∂p_y (broadcastable).
    """
    return distance_rows_nd(p, pcols, (dpx, dpy), P, d0, station, readings, station_col, dead_path_col)


def distance_rows_nd(p, pcols, dp, P, d0, station, readings, station_col: int, dead_path_col: int):
    """The distance residual of both papers, r = ‖p − P_j‖ − d0_j − d (000 Eq. 10, 001 Eq. 3), batched, mm,
    in D = 2 or 3 dimensions (001 Eq. 3 with p_i, P_j in R^D).

    Args:
        p: (T, K, D) the position of every reading in T parameter vectors, mm.
        pcols, dp: (K, m) the position model's parameter columns and, per coordinate c < D, the
            matching (T, K, m) ∂p_c (broadcastable).
        P, d0: (T, N, D) stations and (T, N) dead paths; ``station`` (K,) the station of each reading.
        readings: (K,) or (T, K) the readings d, mm.
        station_col, dead_path_col: where P_0x and d0_0 sit in the parameter vector (P_j's D coordinates
            consecutive).

    Returns:
        r (T, K); cols (K, m + D + 1) shared by the trials; vals (T, K, m + D + 1): u·∂p, −u on P_j, −1 on
        d0_j (u the unit vector from P_j to p).
    """
    D = p.shape[-1]
    diff = p - P[:, station]
    dist = np.hypot.reduce(diff, axis=-1)  # = np.hypot(dx, dy) bit for bit in 2D
    u = diff / dist[..., None]
    r = dist - d0[:, station] - readings
    dr_dp = u[..., :1] * dp[0]
    for c in range(1, D):
        dr_dp = dr_dp + u[..., c:c + 1] * dp[c]
    cols = np.column_stack([pcols] + [station_col + D * station + c for c in range(D)] + [dead_path_col + station])
    vals = np.concatenate([dr_dp, -u, -np.ones(r.shape + (1,))], axis=-1)
    return r, cols, vals


class Calibration(LeastSquaresProgram):
    """The calibration program of a measurement (see the module docstring), units of the measurement (mm, deg).

    ``gauge``: an object with ``A``, ``b`` (A x = b over the measurement's names) and ``sentence``
    (e.g. :func:`olti_drake.model.serial.find_gauge`'s), or None. ``source``: what the readings came from,
    for the messages. Build, optionally add to :attr:`prog`, then :meth:`fit` (or ``Solve(prog)``).
    """

    def __init__(self, measurement, options: SolverOptions = None, gauge=None, source: str = "campaign"):
        self.measurement = measurement
        self._source = source
        self._declare(list(measurement.names), options or SolverOptions())
        self.x0 = measurement.start_vector()
        self.gauge = "none"
        if gauge is not None:
            self.prog.AddLinearEqualityConstraint(np.asarray(gauge.A, float), np.asarray(gauge.b, float),
                                                  self.variables).evaluator().set_description("gauge")
            self.gauge = gauge.sentence

    @property
    def source(self) -> str:
        return self._source

    def residuals(self, x):
        return self.measurement.residuals(np.asarray(x, dtype=float))

    def beam_lengths(self, x) -> np.ndarray:
        return self.measurement.beam_lengths(np.asarray(x, dtype=float))

    def layout(self, v) -> dict:
        return self.measurement.layout(np.asarray(v, dtype=float))


def station_fit(points_mm, readings_mm, start_mm=None):
    """(P, L0) of one station from known points p (K, D), D = 2 or 3, and readings d = ‖p − P‖ − L0 (K,), mm.

    Without a start: the linearized multilateration ‖p‖² − 2p·P + ‖P‖² =
    (d + L0)² is linear in (P, L0, ‖P‖² − L0²); then Gauss-Newton on Eq. (3)
    of 001 (Eq. (5) of 000 for a SCARA reflector; the 3D station of an N-joint robot).
    """
    p, d = np.asarray(points_mm, dtype=float), np.asarray(readings_mm, dtype=float)
    D = p.shape[1]
    if np.linalg.matrix_rank(p - p.mean(axis=0), tol=1e-9 * max(1.0, np.abs(p).max())) < D:
        raise ValueError(f"the points lie on one {'line' if D == 2 else 'plane'}: distances cannot tell the two "
                         f"sides of it apart")
    if start_mm is None:
        A = np.column_stack([-2 * p, -2 * d, np.ones(len(d))])
        sol, *_ = np.linalg.lstsq(A, d ** 2 - np.sum(p ** 2, axis=1), rcond=None)
        P, L0 = sol[:D], sol[D]
    else:
        P = np.asarray(start_mm, dtype=float)
        L0 = np.mean(np.hypot.reduce(p - P, axis=1) - d)
    for _ in range(20):
        diff = p - P
        dist = np.hypot.reduce(diff, axis=1)
        J = np.column_stack([-diff / dist[:, None], -np.ones(len(d))])
        # D + 1 unknowns, the points spread (checked above): the normal equations, ~5x cheaper than lstsq here.
        step = np.linalg.solve(J.T @ J, -(J.T @ (dist - L0 - d)))
        P, L0 = P + step[:D], L0 + step[D]
        if np.max(np.abs(step)) < 1e-12:
            break
    return P, L0


def _norms(diff) -> np.ndarray:
    """Row lengths; np.hypot in 2D (the arithmetic the SCARA and machine results were written with)."""
    return np.hypot(*diff.T) if diff.shape[1] == 2 else np.linalg.norm(diff, axis=1)
