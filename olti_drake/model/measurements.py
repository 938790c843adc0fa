"""What a distance reading sees of a position model: the distance residual of both papers, and the distance
measurement from stations over any position model that gives its points in row-compressed form.

Paper 000 Eq. (5)/(10) (a SCARA reflector P_j with dead path d0_j) and paper 001 Eq. (3) (a machine-tool
station P_j with dead path L0_j) read the same thing: d = ‖p − P_j‖ − d0_j, so the residual of every
distance reading is r = ‖p − P_j‖ − d0_j − d (mm).

* :func:`distance_residual`: that residual and its unit vector u (∂r/∂p = u, ∂r/∂P_j = −u, ∂r/∂d0_j = −1)
  in D = 2 or 3 dimensions -- the one place it is written; the serial robot's
  :class:`olti_drake.model.serial.DistanceMeasurement` (stations in 3D or in a planar robot's plane, dead-path
  drift) contracts u with its own ``PositionJacobian``.
* :func:`distance_rows_nd` (and its 2D form :func:`distance_rows`): that residual and its Jacobian rows,
  batched over T parameter vectors, in D = 2 or 3 dimensions (the SCARA
  :class:`~olti_drake.estimation.identification.Identifier`, the multilateration of 001 and the volumetric
  machine, its identification and its observability check, use it).
* :class:`StationDistanceMeasurement`: distance readings from N_j stations (P_j ∈ R^D, dead paths) of the
  points of a position model (e.g. the free points of 001, :class:`olti_drake.model.free_points.FreePoints`, or
  the tool points of the volumetric machine, :class:`olti_drake.model.volumetric3d.VolumetricPositionModel`):
  the *measurement* object :class:`olti_drake.estimation.calibration.Calibration` takes (``names``,
  ``start_vector()``, ``residuals(x) -> (r, sparse dr/dx)``, ``beam_lengths(x, residuals)``, ``layout(v)``),
  plus the batched :meth:`~StationDistanceMeasurement.residual_rows` of the Monte Carlo.

Units: mm (parameters, readings, residuals; the Jacobian mm/mm).
"""

import numpy as np

from olti_drake.model.scara import rows_to_csr


def lengths(diff) -> np.ndarray:
    """‖diff‖ over the last axis (D = 2 or 3), mm: np.hypot chained over the coordinates -- bit for bit
    ``np.hypot.reduce(diff, axis=-1)``, 4-6x faster on (T, K, D) (a reduction over a short last axis is slow)."""
    dist = np.hypot(diff[..., 0], diff[..., 1])
    for c in range(2, diff.shape[-1]):
        dist = np.hypot(dist, diff[..., c])
    return dist


def distance_residual(p, P, d0, readings):
    """The distance residual of both papers, r = ‖p − P_j‖ − d0_j − d (000 Eq. 10, 001 Eq. 3), mm, and its
    unit vector u = (p − P_j) / ‖p − P_j‖ -- the one place it is written.

    The derivatives follow from u: ∂r/∂p = u, ∂r/∂P_j = −u, ∂r/∂d0_j = −1 (mm/mm); each caller contracts u
    with its own ∂p/∂x (:func:`distance_rows_nd` row-compressed, the serial robot's
    :class:`olti_drake.model.serial.DistanceMeasurement` through its ``PositionJacobian``).

    Args:
        p: (..., D) the position of every reading (D = 2 or 3), mm.
        P: (..., D) the station of every reading (broadcastable), mm.
        d0: (...) the dead path of every reading (a drift included), mm.
        readings: (...) the readings d, mm.

    Returns:
        r (...) mm; u (..., D).
    """
    diff = p - P
    dist = lengths(diff)  # = np.hypot(dx, dy) bit for bit in 2D
    return dist - d0 - readings, diff / dist[..., None]


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
    r, u = distance_residual(p, P[:, station], d0[:, station], readings)
    dr_dp = u[..., :1] * dp[0]
    for c in range(1, D):
        dr_dp = dr_dp + u[..., c:c + 1] * dp[c]
    cols = np.column_stack([pcols] + [station_col + D * station + c for c in range(D)] + [dead_path_col + station])
    vals = np.concatenate([dr_dp, -u, -np.ones(r.shape + (1,))], axis=-1)
    return r, cols, vals


class StationDistanceMeasurement:
    """Distance readings of a position model's points from stations, 001 Eq. (3) in D = 2 or 3 dimensions:
    r_k = ‖p_i − P_j‖ − L0_j − ΔL_k (mm) for reading k of point i = ``points[k]`` from station j =
    ``station[k]`` (000 Eq. (10) alike, its dead path d0_j).

    ``model``: a position model offering ``names``, ``n_params``, ``dim``, ``start_vector()``,
    ``positions(x)`` (N, D) and the batched rows ``rows(X, points) -> (p (T, K, D), cols (K, m), dp)`` (dp: per
    coordinate c the (T, K, m) ∂p_c, broadcastable) -- e.g. :class:`olti_drake.model.free_points.FreePoints`, the
    SCARA closed form :class:`olti_drake.model.scara.ScaraPositionModel` (000 Eq. 10: its reflectors P_j and dead
    paths d0_j, ``dead_path="d0"``), or the volumetric machine's tool points
    :class:`olti_drake.model.volumetric3d.VolumetricPositionModel`.

    Parameters (``names``): the model's, then ``P{j}_x_mm, P{j}_y_mm`` (, ``P{j}_z_mm``) per station, then
    ``{dead_path}_{j}_mm`` per station (``dead_path``: ``L0`` as in 001, ``d0`` as in 000), j = 0 ..
    ``n_stations`` − 1. ``stations_mm`` (N_j, D) and ``dead_paths_mm`` (N_j,) are the start of the stations'
    parameters (default zero).
    """

    kind = "distance"
    #: A station farther than this many spans of the model's start points from their centroid is absurd.
    STATION_SPANS = 100.0

    def __init__(self, model, points, station, displacement_mm, stations_mm=None, dead_paths_mm=None,
                 n_stations=None, dead_path: str = "L0"):
        self.model = model
        self.dim = D = int(model.dim)
        self.points = np.asarray(points)
        self.station = np.asarray(station)
        self.displacement = np.asarray(displacement_mm, dtype=float)
        if not (self.points.shape == self.station.shape == self.displacement.shape):
            raise ValueError("distance measurement: points, station and displacement differ in length")
        self.n_stations = int(self.station.max()) + 1 if n_stations is None else int(n_stations)
        axes = "xyz"[:D]
        self.own_names = tuple(f"P{j}_{c}_mm" for j in range(self.n_stations) for c in axes) + tuple(
            f"{dead_path}_{j}_mm" for j in range(self.n_stations))
        P = (np.zeros((self.n_stations, D)) if stations_mm is None
             else np.asarray(stations_mm, dtype=float).reshape(self.n_stations, D))
        d0 = np.zeros(self.n_stations) if dead_paths_mm is None else np.asarray(dead_paths_mm, dtype=float)
        self._own_start = np.concatenate([P.ravel(), d0.reshape(self.n_stations)])
        self.n_model = int(model.n_params)
        self.station_col = self.n_model  # P_0x
        self.dead_path_col = self.n_model + D * self.n_stations  # L0_0

    @property
    def names(self):
        return tuple(self.model.names) + self.own_names

    def reading_spans(self):
        """(the widest spread of one station's readings, the spread of the points the start model reads them at),
        mm: readings spread far less than the points move are in another unit (metres?) -- the engine's unit-slip
        checks (:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.residual_warnings`, ``_real_cause``)."""
        if not len(self.displacement):
            return 0.0, 0.0
        spread = max(float(np.ptp(self.displacement[self.station == j])) for j in np.unique(self.station))
        p = np.asarray(self.model.positions(self.model.start_vector()), dtype=float)
        return spread, float(np.ptp(p.reshape(-1, self.dim), axis=0).max())

    def roughness(self, **model_options):
        """The position model's roughness rows over all of :attr:`names` (:func:`own_roughness`)."""
        return own_roughness(self.model, len(self.own_names), **model_options)

    def start_vector(self) -> np.ndarray:
        return np.concatenate([self.model.start_vector(), self._own_start])

    def split(self, x):
        """(model part, stations (N_j, D), dead paths (N_j,)) of a parameter vector (views, mm)."""
        x = np.asarray(x)
        return (x[:self.n_model], x[self.station_col:self.dead_path_col].reshape(-1, self.dim),
                x[self.dead_path_col:])

    def residual_rows(self, X, displacement_mm=None):
        """001 Eq. (3) for T parameter vectors at once, the Jacobian row-compressed (for the Monte Carlo).

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`), mm.
            displacement_mm: readings (K,) or per trial (T, K), mm; default the measurement's.

        Returns:
            r (T, K) = ‖p_i − P_j‖ − L0_j − ΔL, mm; cols (K, m + D + 1) parameter indices shared by all
            trials (the model's columns of p_i; P_j coordinates; L0_j); vals (T, K, m + D + 1) the matching
            dr/dx entries (u·∂p_i, −u, −1), u the unit vector from P_j to p_i.
        """
        X = np.atleast_2d(X)
        p, pcols, dp = self.model.rows(X, self.points)
        P = X[:, self.station_col:self.dead_path_col].reshape(len(X), self.n_stations, self.dim)
        readings = self.displacement if displacement_mm is None else displacement_mm
        return distance_rows_nd(p, pcols, dp, P, X[:, self.dead_path_col:], self.station, readings,
                                self.station_col, self.dead_path_col)

    def residuals(self, x):
        """001 Eq. (3): r (K,) = ‖p_i − P_j‖ − L0_j − ΔL (mm) and the sparse dr/dx (K, n) as CSR."""
        r, cols, vals = self.residual_rows(np.asarray(x)[None])
        return r[0], rows_to_csr(cols, vals[0], len(self.names))

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """‖p_i − P_j‖ of every reading at x, mm (from the ``residuals`` at x when given: r + L0_j + ΔL)."""
        r = self.residuals(x)[0] if residuals is None else residuals
        return r + self.split(x)[2][self.station] + self.displacement

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values or uncertainties) in result.json's keys (formats.md): the model's,
        then ``stations_mm`` (N_j, D) and ``dead_paths_mm`` (N_j,)."""
        vm, stations, dead = self.split(np.asarray(v, dtype=float))
        return {**self.model.layout(vm, uncertainty), "stations_mm": stations.tolist(),
                "dead_paths_mm": dead.tolist()}

    def implausible(self, x) -> list:
        """Stations beyond :attr:`STATION_SPANS` spans of the model's start points from their centroid (the
        command centroid and span of a machine; a model with ``station_reference() -> (centre, span, its name)``
        gives its own, e.g. the volumetric machine's travel diagonal), then the model's own implausible values;
        one phrase each."""
        xm, stations, _ = self.split(x)
        reference = getattr(self.model, "station_reference", None)
        if reference is not None:
            centre, span, what = reference()
        else:
            c = self.model.positions(self.model.start_vector())
            centre, span, what = c.mean(axis=0), max(float(np.ptp(c, axis=0).max()), 1e-9), "the command span"
        out = []
        far = np.hypot.reduce(stations - centre, axis=1)
        if far.max() > self.STATION_SPANS * span:
            j = int(np.argmax(far))
            out.append(f"station {j} lies {far[j]:.6g} mm from the command centroid, over {self.STATION_SPANS:g} "
                       f"x {what} {span:g} mm")
        return out + list(self.model.implausible(xm))


def own_roughness(model, n_own: int, **model_options):
    """The model's roughness rows (its maps' smoothness prior, when it has maps; ``model_options`` passed on to its
    ``roughness``) padded with zeros for a measurement's ``n_own`` own parameters (stations, dead paths, frames
    have none); None when the model has no maps."""
    rows = getattr(model, "roughness", None)
    R = rows(**model_options) if rows is not None else None
    if R is None:
        return None
    import scipy.sparse as sp

    return sp.hstack([R, sp.csr_matrix((R.shape[0], n_own))], format="csr")
