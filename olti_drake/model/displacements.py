"""What an R-test / 3D probe and a laser tracker see of a position model, and one campaign that mixes readings.

The five-axis campaign of formats.md ("Five-axis machine tools") reads the tool point p_i(x) of any position model
of dimension 3 (:mod:`olti_drake.model.position_model`: the volumetric machine, the free points of 001, the
five-axis machine) in three ways; the distances from stations are
:class:`olti_drake.model.measurements.StationDistanceMeasurement` (000 Eq. 10 / 001 Eq. 3). Here:

* :class:`NestDisplacementMeasurement` -- R-test / 3D-probe readings (the K-tests of ISO 10791-6):
  d_k = p_i − c_n, the displacement of the spindle ball's centre from nest n's zero in the workpiece frame, so
  r_k = p_i(x) − c_n − d_k (3 rows per reading, mm). Each nest set-up has its own unknown zero c_n (3 parameters,
  mm). Gauge: a nest zero absorbs a common translation of the points it sees -- a nest read alone tells
  nothing of where its points are, only their displacements from one another.
* :class:`PointMeasurement` -- tracker points m_k in the tracker's own frame: r_k = R(w_g) p_i(x) + t_g − m_k (3 rows
  per reading, mm), one unknown rigid transform per tracker set-up g: translation t_g (mm) and rotation vector w_g
  (µrad, R(w) = exp([w]×) -- µrad as the angular error motions of ISO 230-1 in this package: one µrad at a
  1 m lever moves a point one µm, so a frame's u in µrad is of the order of the readings' u in µm). Gauge: a
  tracker frame absorbs a rigid motion (3 translations, 3 rotations) of the points it sees.
  :func:`~olti_drake.model.frames.rigid_fit` (Kabsch) starts each frame. The serial robot's
  :class:`olti_drake.model.serial.PointMeasurement` is the same residual with fixed angles in deg
  (:mod:`olti_drake.model.frames` holds both conventions and their Jacobian).
* :class:`CombinedMeasurement` -- several measurements of one model sharing its parameters, each with its own
  (stations, nests, tracker frames), residuals stacked; each measurement's rows weighed by its reading
  uncertainty σ (its ``sigma_mm``): rows scaled by σ_ref / σ_i, σ_ref = the first measurement's σ, so the engine's
  equal-weight least squares (:class:`olti_drake.estimation.calibration.Calibration`) is the weighted one and its
  residuals stay in mm of the first measurement's readings (what a budget given to the engine describes).

Each offers what :class:`~olti_drake.estimation.calibration.Calibration` and the Monte Carlo
(:func:`olti_drake.estimation.uncertainty.monte_carlo`) read of a measurement: ``names``, ``own_names``,
``start_vector()``, ``residuals(x) -> (r, CSR dr/dx)``, the batched ``residual_rows(X, readings)``, ``split``,
``beam_lengths``, ``layout``, ``roughness``, ``implausible``, ``reading_spans``. Residual rows of the 3-row kinds:
x, y, z of reading 0, then reading 1, ... Units: mm (points, readings, nests, translations), µrad (rotation
vectors); the Jacobian mm/(model units), mm/mm, mm/µrad.
"""

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.model.frames import URAD, left_jacobian, rigid_fit, rotation_matrix, rotation_vector, turn_rows
from olti_drake.model.measurements import own_roughness
from olti_drake.model.scara import rows_to_csr


# ----------------------------------------------------------------------------------------------- checks
def _model_3d(model, what: str) -> int:
    dim = int(getattr(model, "dim", 0))
    if dim != 3:
        raise InputError(f"{what}: the position model must place points in 3D (dim 3), got dim {dim}")
    return dim


def _indices(values, name: str, upper=None) -> np.ndarray:
    """Non-negative integer indices (K,), refused in one line naming ``name`` and the first bad row."""
    a = np.asarray(values)
    if a.ndim != 1:
        raise InputError(f"{name}: one index per reading expected, got shape {a.shape}")
    try:
        f = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        f = np.array([_number(v) for v in a])
    bad = ~np.isfinite(f) | (f != np.round(f)) | (f < 0) | ((f >= upper) if upper is not None else False)
    if bad.any():
        k = int(np.argmax(bad))
        bound = f" below {upper}" if upper is not None else ""
        raise InputError(f"{name}: row {k} is {a[k]!r}, not a whole number >= 0{bound}")
    return f.astype(int)


def _number(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return np.nan


def _xyz(values, name: str, rows: int) -> np.ndarray:
    """(rows, 3) finite mm, refused in one line naming ``name`` and the first bad row."""
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name}: numbers (mm) expected") from None
    if a.shape != (rows, 3):
        raise InputError(f"{name}: {rows} rows of x, y, z (mm) expected, got shape {a.shape}")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise InputError(f"{name}: row {int(np.argmax(bad))} is not finite ({a[int(np.argmax(bad))].tolist()})")
    return a


def _vector(x, n: int) -> np.ndarray:
    """x as an (n,) parameter vector, refused in one line when its length is not the measurement's."""
    x = np.asarray(x)
    if x.shape != (n,):
        raise InputError(f"parameter vector: {x.size} values, the measurement has {n} parameters")
    return x


def _sigma(sigma_mm, name: str):
    if sigma_mm is None:
        return None
    s = float(sigma_mm)
    if not (np.isfinite(s) and s > 0):
        raise InputError(f"{name}: the reading uncertainty must be finite and > 0 mm, got {sigma_mm!r}")
    return s


def _reference(model):
    """(centre mm, span mm, its name) a far set-up (nest, tracker) is judged by (as the stations' check)."""
    ref = getattr(model, "station_reference", None)
    if ref is not None:
        return ref()
    c = np.asarray(model.positions(model.start_vector()), float)
    return c.mean(axis=0), max(float(np.ptp(c, axis=0).max()), 1e-9), "the span of the points"


def _broadcast_dp(dp, shape):
    """The model's ∂p_c rows (per coordinate, broadcastable) as one (T, K, 3, m) array."""
    return np.stack([np.broadcast_to(d, shape) for d in dp], axis=2)


# ------------------------------------------------------------------------------------ R-test / 3D probe
class _GroupedPoints:
    """What the nest and tracker measurements share: readings of 3 coordinates (mm) of the model's points
    ``points``, each reading in a set-up (a nest, a tracker frame: ``labels``, the index ``index``) with
    :attr:`width` unknowns of its own after the model's."""

    width = 3

    def _setup(self, model, points, groups, values, value_name: str, group_name: str, what: str, sigma_mm,
               sigma_name: str) -> None:
        self.model = model
        self.dim = _model_3d(model, what)
        self.points = _indices(points, "points", int(model.n_points))
        self.values = _xyz(values, value_name, len(self.points))
        labels = _indices(groups, group_name)
        if len(labels) != len(self.points):
            raise InputError(f"{group_name}: {len(labels)} values for {len(self.points)} readings (one per reading)")
        if not len(labels):
            raise InputError(f"{what}: no readings")
        self.labels, index = np.unique(labels, return_inverse=True)
        self.index = index.ravel()
        self.sigma_mm = _sigma(sigma_mm, sigma_name)
        self.n_model = int(model.n_params)
        self.own_col = self.n_model

    @property
    def names(self):
        return tuple(self.model.names) + self.own_names

    @property
    def n_rows(self) -> int:
        return 3 * len(self.points)

    @property
    def readings(self) -> np.ndarray:
        """The readings per residual row (3K,) mm: x, y, z (or dx, dy, dz) of reading 0, then reading 1, ..."""
        return self.values.ravel()

    def start_vector(self) -> np.ndarray:
        return np.concatenate([self.model.start_vector(), self._own_start])

    def split(self, x):
        """(model part, the set-ups' own unknowns (N, :attr:`width`)) of a parameter vector (views)."""
        x = _vector(x, len(self.names))
        return x[:self.n_model], x[self.own_col:].reshape(-1, self.width)

    def residuals(self, x):
        """r (3K,) mm and the sparse dr/dx (3K, n) as CSR (:meth:`residual_rows` of one vector)."""
        r, cols, vals = self.residual_rows(np.asarray(x, float)[None])
        jac = rows_to_csr(cols, vals[0], len(self.names))
        jac.sum_duplicates()
        return r[0], jac

    def roughness(self, **model_options):
        return own_roughness(self.model, len(self.own_names), **model_options)

    def reading_spans(self):
        """(the widest spread of one set-up's readings, the widest spread of the start points it sees), mm:
        readings spread far less than the points they are read at are in another unit (the engine's checks)."""
        p = np.asarray(self.model.positions(self.model.start_vector()), float)[self.points]
        spread = motion = 0.0
        for j in range(len(self.labels)):
            sel = self.index == j
            spread = max(spread, float(np.ptp(self.values[sel], axis=0).max()))
            motion = max(motion, float(np.ptp(p[sel], axis=0).max()))
        return spread, motion


class NestDisplacementMeasurement(_GroupedPoints):
    """R-test / 3D-probe readings of a position model's points from nests (ISO 10791-6, ISO 230-7 R-test;
    formats.md "Five-axis machine tools"): reading k is the displacement d_k (dx, dy, dz mm, workpiece frame) of
    point i = ``points[k]`` (the spindle ball's centre) from the zero c_n of nest n = ``nest[k]``:
    r_k = p_i(x) − c_n − d_k (3 rows per reading, mm).

    ``model``: a position model of dim 3 (:class:`~olti_drake.model.position_model.PositionModel`).
    Parameters (``names``): the model's, then ``nest{n}_x_mm, nest{n}_y_mm, nest{n}_z_mm`` per nest label n
    (the distinct values of ``nest``, ascending). ``nests_start_mm`` (N_n, 3): their start; default the least
    squares zero at the start model, c_n = mean over its readings of (p_i(x0) − d_k). ``sigma_mm``: the standard
    uncertainty of one coordinate of a reading (for :class:`CombinedMeasurement`), or None.

    Gauge: a nest zero absorbs a common translation of the points it sees (:attr:`GAUGE`).
    """

    kind = "nest"
    GAUGE = "each nest zero absorbs a common translation of the points it sees"
    #: A nest zero farther than this many spans of its points (or of its largest reading) from them is absurd.
    NEST_SPANS = 100.0

    def __init__(self, model, points, nest, displacement_mm, nests_start_mm=None, sigma_mm=None):
        self._setup(model, points, nest, displacement_mm, "displacement_mm (dx_mm, dy_mm, dz_mm)", "nest",
                    "nest displacement measurement", sigma_mm, "sigma_mm of the nest readings")
        self.displacement, self.nest, self.nest_col = self.values, self.index, self.own_col
        self.n_nests = len(self.labels)
        self.own_names = tuple(f"nest{j}_{c}_mm" for j in self.labels for c in "xyz")
        self._own_start = (self._start_nests() if nests_start_mm is None else
                           _xyz(nests_start_mm, "nests_start_mm", self.n_nests)).ravel()

    def _start_nests(self) -> np.ndarray:
        """c_n = mean of p_i(x0) − d_k over nest n's readings: the least-squares zero at the start model."""
        p = np.asarray(self.model.positions(self.model.start_vector()), float)[self.points] - self.displacement
        sums = np.zeros((self.n_nests, 3))
        np.add.at(sums, self.nest, p)
        return sums / np.bincount(self.nest, minlength=self.n_nests)[:, None]

    def residual_rows(self, X, displacement_mm=None):
        """r = p_i − c_n − d for T parameter vectors at once, the Jacobian row-compressed (the Monte Carlo's).

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`).
            displacement_mm: readings per row (3K,) or per trial (T, 3K), mm; default the measurement's.

        Returns:
            r (T, 3K) mm; cols (3K, m + 1) shared by the trials (the model's columns of p_i, then c_n's
            coordinate); vals (T, 3K, m + 1): ∂p_c/∂x, then −1.
        """
        X = np.atleast_2d(X)
        T, K = len(X), len(self.points)
        p, pcols, dp = self.model.rows(X, self.points)
        m = pcols.shape[1]
        c = X[:, self.nest_col:].reshape(T, self.n_nests, 3)[:, self.nest]
        d = self.readings if displacement_mm is None else displacement_mm
        r = (p - c).reshape(T, 3 * K) - d
        own = self.nest_col + 3 * self.nest[:, None] + np.arange(3)[None, :]  # (K, 3)
        cols = np.concatenate([np.repeat(pcols[:, None, :], 3, axis=1), own[..., None]], axis=2)
        vals = np.concatenate([_broadcast_dp(dp, (T, K, m)), -np.ones((T, K, 3, 1))], axis=3)
        return r, cols.reshape(3 * K, m + 1), vals.reshape(T, 3 * K, m + 1)

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """An R-test or probe has no beam: 0 mm per row (a budget's cosine term vanishes; its constant parts
        stay)."""
        return np.zeros(self.n_rows)

    def layout(self, v, uncertainty: bool = False) -> dict:
        """The model's keys, then ``nests_mm`` (N_n, 3) and ``nest_labels``."""
        vm, nests = self.split(np.asarray(v, float))
        return {**self.model.layout(vm, uncertainty), "nests_mm": nests.tolist(),
                "nest_labels": [int(j) for j in self.labels]}

    def implausible(self, x) -> list:
        """Nest zeros beyond :attr:`NEST_SPANS` x (the span of the points they see, their largest reading,
        1 mm) from those points' centroid, then the model's implausible values; one phrase each."""
        xm, nests = self.split(np.asarray(x, float))
        p = np.asarray(self.model.positions(xm), float)[self.points]
        out = []
        for j, label in enumerate(self.labels):
            sel = self.nest == j
            reach = max(float(np.ptp(p[sel], axis=0).max()), float(np.abs(self.displacement[sel]).max()), 1.0)
            far = float(np.linalg.norm(nests[j] - p[sel].mean(axis=0)))
            if far > self.NEST_SPANS * reach:
                out.append(f"nest {label} (nest{label}_*_mm) lies {far:.6g} mm from the points it reads, over "
                           f"{self.NEST_SPANS:g} x their reach {reach:.6g} mm")
        return out + list(self.model.implausible(xm))


# ----------------------------------------------------------------------------------------------- tracker
class PointMeasurement(_GroupedPoints):
    """Tracker points of a position model's points in the tracker's own frame (formats.md "Five-axis machine
    tools": ``x_mm, y_mm, z_mm``): reading k of point i = ``points[k]`` by tracker set-up g = ``frame_group[k]``
    is m_k = R(w_g) p_i + t_g, so r_k = R(w_g) p_i(x) + t_g − m_k (3 rows per reading, mm).

    Parameters (``names``): the model's, then per set-up label g (the distinct values of ``frame_group``,
    ascending) ``frame{g}_x_mm, frame{g}_y_mm, frame{g}_z_mm`` (t_g) and ``frame{g}_rx_urad, frame{g}_ry_urad,
    frame{g}_rz_urad`` (the rotation vector w_g, µrad; R(w) = exp([w]×)). ``frames_start`` (G, 6): their start;
    default the Kabsch fit (:func:`rigid_fit`) of the start model's points to each set-up's readings.
    ``sigma_mm``: the standard uncertainty of one coordinate of a reading, or None.

    Gauge: a tracker frame absorbs a rigid motion of the points it sees (:attr:`GAUGE`). The Jacobian is exact
    for any rotation (the left Jacobian of SO(3), :func:`left_jacobian`).
    """

    kind = "point"
    GAUGE = "each tracker frame absorbs a rigid motion (3 translations, 3 rotations) of the points it sees"
    #: A tracker farther than this many spans of the model's points from their centre is absurd.
    STATION_SPANS = 100.0

    width = 6

    def __init__(self, model, points, frame_group, xyz_mm, frames_start=None, sigma_mm=None):
        self._setup(model, points, frame_group, xyz_mm, "xyz_mm (x_mm, y_mm, z_mm)", "frame_group",
                    "tracker point measurement", sigma_mm, "sigma_mm of the tracker points")
        self.xyz, self.group, self.frame_col = self.values, self.index, self.own_col
        self.n_frames = len(self.labels)
        self.own_names = tuple(f"frame{g}_{c}" for g in self.labels
                               for c in ("x_mm", "y_mm", "z_mm", "rx_urad", "ry_urad", "rz_urad"))
        if frames_start is None:
            self._own_start = self._start_frames().ravel()
        else:
            f = np.asarray(frames_start, float)
            if f.shape != (self.n_frames, 6) or not np.isfinite(f).all():
                raise InputError(f"frames_start: {self.n_frames} rows of finite t (mm) and w (µrad) expected, got "
                                 f"shape {f.shape}")
            self._own_start = f.ravel()

    def _start_frames(self) -> np.ndarray:
        """(G, 6) per set-up: the Kabsch fit m ≈ R p + t of the start model's points (t mm, w µrad)."""
        p = np.asarray(self.model.positions(self.model.start_vector()), float)[self.points]
        out = np.zeros((self.n_frames, 6))
        for j, label in enumerate(self.labels):
            sel = self.group == j
            try:
                R, t = rigid_fit(p[sel], self.xyz[sel])
            except InputError as e:
                raise InputError(f"tracker set-up {label}: {e}") from None
            out[j] = np.concatenate([t, rotation_vector(R) / URAD])
        return out

    def residual_rows(self, X, xyz_mm=None):
        """r = R(w_g) p_i + t_g − m for T parameter vectors at once, the Jacobian row-compressed.

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`).
            xyz_mm: readings per row (3K,) or per trial (T, 3K), mm; default the measurement's.

        Returns:
            r (T, 3K) mm; cols (3K, m + 4): the model's columns of p_i, t_g's coordinate, w_g's three; vals
            (T, 3K, m + 4): R ∂p/∂x, 1, −[R p]× J_l(w) · 1e-6 (mm/µrad).
        """
        X = np.atleast_2d(X)
        T, K = len(X), len(self.points)
        p, pcols, dp = self.model.rows(X, self.points)
        m = pcols.shape[1]
        frames = X[:, self.frame_col:].reshape(T, self.n_frames, 6)
        w = frames[..., 3:] * URAD
        R = rotation_matrix(w)[:, self.group]  # (T, K, 3, 3)
        q = np.einsum("tkac,tkc->tka", R, p)
        readings = self.readings if xyz_mm is None else xyz_mm
        r = (q + frames[:, self.group, :3]).reshape(T, 3 * K) - readings
        d_model = np.einsum("tkac,tkcm->tkam", R, _broadcast_dp(dp, (T, K, m)))
        d_rot = turn_rows(q, left_jacobian(w)[:, self.group], URAD)  # (T, K, 3, 3)
        base = self.frame_col + 6 * self.group  # (K,)
        cols = np.concatenate([np.repeat(pcols[:, None, :], 3, axis=1),
                               (base[:, None] + np.arange(3)[None, :])[..., None],
                               np.repeat((base[:, None] + 3 + np.arange(3)[None, :])[:, None, :], 3, axis=1)],
                              axis=2)
        vals = np.concatenate([d_model, np.ones((T, K, 3, 1)), d_rot], axis=3)
        return r, cols.reshape(3 * K, m + 4), vals.reshape(T, 3 * K, m + 4)

    def predict(self, x) -> np.ndarray:
        """The points in their set-up's tracker frame (K, 3) mm: the residual of zero readings."""
        return self.residual_rows(np.asarray(x, float)[None], np.zeros(self.n_rows))[0][0].reshape(-1, 3)

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """The distance from the tracker (its frame's origin) to every point at x, per row (3K,) mm
        (``residuals`` at x: their reading + r)."""
        q = (self.readings + residuals).reshape(-1, 3) if residuals is not None else self.predict(x)
        return np.repeat(np.linalg.norm(q, axis=1), 3)

    def layout(self, v, uncertainty: bool = False) -> dict:
        """The model's keys, then ``tracker_frames``: per set-up its translation (mm) and rotation vector (µrad)."""
        vm, frames = self.split(np.asarray(v, float))
        return {**self.model.layout(vm, uncertainty), "tracker_frames": [
            {"set_up": int(g), "translation_mm": f[:3].tolist(), "rotation_vector_urad": f[3:].tolist(),
             "convention": "tracker point = R(w) p + t, R(w) = exp([w]x), w in urad"}
            for g, f in zip(self.labels, frames)]}

    def implausible(self, x) -> list:
        """A tracker (its origin in the model's frame, −Rᵀt) beyond :attr:`STATION_SPANS` x the model's span from
        its centre (``station_reference()`` when the model has one), then the model's implausible values."""
        xm, frames = self.split(np.asarray(x, float))
        centre, span, what = _reference(self.model)
        out = []
        for g, f in zip(self.labels, frames):
            origin = -rotation_matrix(f[3:] * URAD).T @ f[:3]
            far = float(np.linalg.norm(origin - centre))
            if far > self.STATION_SPANS * span:
                out.append(f"tracker set-up {g} (frame{g}_*) lies {far:.6g} mm from the points' centre, over "
                           f"{self.STATION_SPANS:g} x {what} {span:g} mm")
        return out + list(self.model.implausible(xm))


# ---------------------------------------------------------------------------------------------- combined
class CombinedMeasurement:
    """Several measurements of one position model in one campaign (formats.md: "one campaign may mix them"):
    distances (:class:`~olti_drake.model.measurements.StationDistanceMeasurement`), R-test
    (:class:`NestDisplacementMeasurement`), tracker points (:class:`PointMeasurement`).

    Parameters (``names``): the model's (shared), then each measurement's own in the order given (their names
    must differ: one measurement per reading kind, its stations / nests / set-ups numbered within it).
    Residuals: each measurement's rows, stacked in the order given, scaled by σ_ref / σ_i where σ_i is the
    reading uncertainty of measurement i (``sigmas_mm[i]``; where None or not given, its ``sigma_mm``; mm)
    and σ_ref = σ_0: the
    engine's least squares is then the weighted one (JCGM 100 weights 1/σ²), its residuals in mm of measurement
    0's readings and its residual variance σ_ref². Without any σ the rows are unscaled (equal weights); a σ given
    for some measurements and not others is refused.
    """

    kind = "combined"

    def __init__(self, model, measurements: Sequence, sigmas_mm=None):
        self.model = model
        self.measurements = list(measurements)
        if not self.measurements:
            raise InputError("combined measurement: no measurements")
        self.n_model = int(model.n_params)
        for i, m in enumerate(self.measurements):
            if getattr(m, "model", None) is not model:
                raise InputError(f"combined measurement: measurement {i} ({getattr(m, 'kind', type(m).__name__)}) "
                                 f"reads another position model (all must share one)")
            for need in ("own_names", "residual_rows", "residuals", "start_vector"):
                if not hasattr(m, need):
                    raise InputError(f"combined measurement: measurement {i} ({type(m).__name__}) has no {need}")
        self._check_names()
        self.sigmas = self._sigmas(sigmas_mm)
        self.scales = self.sigmas[0] / self.sigmas
        self.slices, start = [], self.n_model
        for m in self.measurements:
            self.slices.append(slice(start, start + len(m.own_names)))
            start += len(m.own_names)
        self.own_names = tuple(n for m in self.measurements for n in m.own_names)
        self._rows = [self._n_rows(m) for m in self.measurements]
        self.row_slices = list(_consecutive(self._rows))
        self.dim = int(model.dim)

    def _check_names(self):
        seen = {n: -1 for n in self.model.names}
        for i, m in enumerate(self.measurements):
            for n in m.own_names:
                if n in seen:
                    who = "the model's" if seen[n] < 0 else f"measurement {seen[n]}'s"
                    raise InputError(f"combined measurement: measurement {i}'s parameter {n} repeats {who}: give one "
                                     f"measurement per reading kind (its stations, nests, set-ups numbered within it)")
                seen[n] = i

    def _sigmas(self, sigmas_mm) -> np.ndarray:
        given = [None] * len(self.measurements) if sigmas_mm is None else list(sigmas_mm)
        if len(given) != len(self.measurements):
            raise InputError(f"sigmas_mm: {len(given)} values for {len(self.measurements)} measurements")
        # (an entry None: the measurement's own sigma_mm, e.g. a nest or tracker measurement's)
        given = [getattr(m, "sigma_mm", None) if s is None else s for m, s in zip(self.measurements, given)]
        given = [_sigma(s, f"sigmas_mm[{i}]") for i, s in enumerate(given)]
        if all(s is None for s in given):
            return np.ones(len(given))
        missing = [i for i, s in enumerate(given) if s is None]
        if missing:
            raise InputError(f"sigmas_mm: measurement {missing[0]} ({self.measurements[missing[0]].kind}) has no "
                             f"reading uncertainty while others have: give each reading kind its sigma (mm)")
        return np.asarray(given, float)

    @staticmethod
    def _n_rows(m) -> int:
        rows = getattr(m, "n_rows", None)
        return int(rows) if rows is not None else len(m.displacement)

    @property
    def names(self):
        return tuple(self.model.names) + self.own_names

    @property
    def n_rows(self) -> int:
        return int(sum(self._rows))

    def _column_map(self, i) -> np.ndarray:
        """Measurement i's columns (its names) -> the combined columns."""
        s = self.slices[i]
        return np.concatenate([np.arange(self.n_model), np.arange(s.start, s.stop)])

    def part(self, x, i: int) -> np.ndarray:
        """Measurement i's parameter vector (the model's part, then its own) of a combined x (..., n)."""
        x = np.asarray(x)
        return x[..., self._column_map(i)]

    def start_vector(self) -> np.ndarray:
        return np.concatenate([self.model.start_vector()] + [m.start_vector()[self.n_model:]
                                                             for m in self.measurements])

    def split(self, x):
        """(model part, [measurement i's own part, ...]) of a parameter vector (views)."""
        x = _vector(x, len(self.names))
        return x[:self.n_model], [x[s] for s in self.slices]

    def residuals(self, x):
        """The stacked, scaled residuals (mm of measurement 0's readings) and their sparse Jacobian (CSR)."""
        x = np.asarray(x, float)
        rs, Js = [], []
        for i, m in enumerate(self.measurements):
            r, J = m.residuals(self.part(x, i))
            J = sp.csr_matrix(J)
            cmap = self._column_map(i)
            rs.append(self.scales[i] * r)
            Js.append(sp.csr_matrix((self.scales[i] * J.data, cmap[J.indices], J.indptr),
                                    shape=(J.shape[0], len(self.names))))
        return np.concatenate(rs), sp.vstack(Js, format="csr")

    def residual_rows(self, X, readings=None):
        """The stacked, scaled rows for T parameter vectors (the Monte Carlo's fast path): readings (R,) or (T, R)
        in the scaled rows' units (mm of measurement 0), default the measurements' own; cols padded to one width
        by repeating a row's first column with value 0."""
        X = np.atleast_2d(X)
        parts = []
        for i, (m, rows) in enumerate(zip(self.measurements, self.row_slices)):
            d = None if readings is None else np.asarray(readings, float)[..., rows] / self.scales[i]
            r, cols, vals = m.residual_rows(self.part(X, i), d)
            parts.append((self.scales[i] * r, self._column_map(i)[cols], self.scales[i] * vals))
        width = max(p[1].shape[1] for p in parts)
        r = np.concatenate([p[0] for p in parts], axis=1)
        cols = np.concatenate([_pad_cols(p[1], width) for p in parts], axis=0)
        vals = np.concatenate([np.pad(p[2], ((0, 0), (0, 0), (0, width - p[2].shape[2]))) for p in parts], axis=1)
        return r, cols, vals

    def unscaled(self, residuals) -> list:
        """The stacked scaled residuals as each measurement's own (mm of its readings), a list."""
        r = np.asarray(residuals, float)
        return [r[s] / k for s, k in zip(self.row_slices, self.scales)]

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """Each measurement's beam lengths (mm), stacked (what a budget's cosine term reads)."""
        x = np.asarray(x, float)
        parts = self.unscaled(residuals) if residuals is not None else [None] * len(self.measurements)
        return np.concatenate([m.beam_lengths(self.part(x, i), r)
                               for i, (m, r) in enumerate(zip(self.measurements, parts))])

    def layout(self, v, uncertainty: bool = False) -> dict:
        """The model's keys once, then every measurement's own keys (``stations_mm``, ``nests_mm``,
        ``tracker_frames``, ...)."""
        v = np.asarray(v, float)
        out = dict(self.model.layout(v[:self.n_model], uncertainty))
        model_keys = set(out)
        for i, m in enumerate(self.measurements):
            out.update({k: val for k, val in m.layout(self.part(v, i), uncertainty).items() if k not in model_keys})
        out["measurement_sigmas_mm"] = self.sigmas.tolist()
        return out

    def roughness(self, **model_options):
        return own_roughness(self.model, len(self.own_names), **model_options)

    def reading_spans(self):
        """The (spread, motion) of the measurement whose readings spread least against their points: a unit slip
        in one reading kind is seen."""
        spans = [m.reading_spans() for m in self.measurements if hasattr(m, "reading_spans")]
        return min(spans, key=lambda s: s[0] / max(s[1], 1e-300)) if spans else (0.0, 0.0)

    def implausible(self, x) -> list:
        """Every measurement's implausible values (the model's once), one phrase each."""
        x = np.asarray(x, float)
        out = []
        for i, m in enumerate(self.measurements):
            check = getattr(m, "implausible", None)
            out += list(check(self.part(x, i))) if check is not None else []
        return list(dict.fromkeys(out))


def _consecutive(counts):
    start = 0
    for c in counts:
        yield slice(start, start + c)
        start += c


def _pad_cols(cols, width: int) -> np.ndarray:
    """Row-compressed columns padded to ``width`` by repeating each row's first column (its value is padded 0)."""
    extra = width - cols.shape[1]
    return np.hstack([cols, np.repeat(cols[:, :1], extra, axis=1)]) if extra else cols
