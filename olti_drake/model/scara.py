"""SCARA kinematics with the bidirectional error map -- the one kinematic model.

Paper 000: Eq. (3) forward kinematics, Eq. (7)-(9) actual angle from the
command angle through the error map. The simulator (Drake systems) and the
identifier both call these functions.

:class:`ScaraPositionModel` is this closed form as a position model of the one calibration engine (parameter
names, start, positions of the commanded poses, the analytic Jacobian batched and row-compressed,
:class:`ScaraJacobian` in the sparse convention of the other models, result layout, implausible values):
read by the distance measurement of :mod:`olti_drake.model.measurements` (000 Eq. 5 / 10), it is the SCARA
:class:`~olti_drake.estimation.identification.Identifier`.

Units: lengths in **mm**, angles in **degrees** (arguments, results and
Jacobians: dp/dθ is in mm/deg). The trigonometry converts internally.
Frame: origin on the J1 axis, X along the arm at θ1* = θ2* = 0 (000 Fig. 2).

The simulated truth (:class:`TrueRobot` below): The simulated robot's truth in plain numpy (000 Eq. 3 with Eq. 7, and Fig. 2).

The Drake diagram computes the same thing through ``ErrorMapJoint`` and the
``MultibodyPlant``; this numpy twin serves the places that need the truth
without running a diagram (the counter zero, the Eq. (2) search, the tracker
paths, truth.json). Tests hold the two equal.

Units: mm and degrees.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Dict, Optional

import numpy as np
import scipy.sparse as sp

from olti_drake.model.errormap import ErrorMap, NoDeviation


DEG = np.pi / 180.0

#: The paper's robot (Mitsubishi RH-3FRH-5515, 000 Table 1), mm.
PAPER_L1_MM = 325.0
PAPER_L2_MM = 225.0


@dataclass(frozen=True)
class JointCommands:
    """Commanded J1, J2 angles (deg) and approach directions (+1/-1), each (N,).

    ``one_directional``: the file had no direction columns (formats.md: a one-directional campaign); the
    directions are then +1 placeholders, which a single-branch map ignores and a bidirectional one refuses
    (:meth:`ScaraModel.interpolation`)."""

    theta1_deg: np.ndarray
    theta2_deg: np.ndarray
    dir1: np.ndarray
    dir2: np.ndarray
    one_directional: bool = False

    @classmethod
    def without_directions(cls, theta1_deg, theta2_deg) -> "JointCommands":
        """Commands of a file without ``dir1, dir2`` (one-directional; +1 placeholders)."""
        n = np.asarray(theta1_deg).size
        return cls(theta1_deg, theta2_deg, np.ones(n), np.ones(n), one_directional=True)

    def __post_init__(self):
        fields = [f for f in dataclasses.fields(self) if f.name != "one_directional"]
        arrays = [np.asarray(getattr(self, f.name), dtype=float).ravel() for f in fields]
        n = arrays[0].size
        for f, a in zip(fields, arrays):
            if a.size != n:
                raise ValueError(f"joint commands: {f.name} has {a.size} entries, expected {n}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"joint commands: {f.name} contains a non-finite value")
            if f.name.startswith("dir") and not np.all(np.isin(a, (-1.0, 1.0))):
                raise ValueError(f"joint commands: {f.name} must be +1 or -1")
            object.__setattr__(self, f.name, a)

    def __len__(self) -> int:
        return self.theta1_deg.size


def forward_kinematics(theta1_deg, theta2_deg, L1_mm, L2_mm):
    """End-effector XY position and its partial derivatives (Eq. 3 of 000).

    ``theta2_deg`` is the angle of link 2 relative to link 1 *including* any
    offset θ20 (the caller adds it), so p = [L1 c1 + L2 c12, L1 s1 + L2 s12].

    Args:
        theta1_deg, theta2_deg: (N,) actual joint angles, deg.
        L1_mm, L2_mm: link lengths, mm.

    Returns:
        p: (N, 2) position, mm.
        dp: dict of (N, 2) partials: ``theta1`` and ``theta2`` in mm/deg,
            ``L1`` and ``L2`` dimensionless.
    """
    t1 = np.asarray(theta1_deg, dtype=float) * DEG
    t12 = t1 + np.asarray(theta2_deg, dtype=float) * DEG
    u1 = np.stack([np.cos(t1), np.sin(t1)], axis=-1)
    u12 = np.stack([np.cos(t12), np.sin(t12)], axis=-1)
    p = L1_mm * u1 + L2_mm * u12
    perp1 = np.stack([-u1[..., 1], u1[..., 0]], axis=-1)
    perp12 = np.stack([-u12[..., 1], u12[..., 0]], axis=-1)
    d_theta2 = L2_mm * perp12 * DEG
    return p, {"theta1": L1_mm * perp1 * DEG + d_theta2, "theta2": d_theta2,
               "L1": u1, "L2": u12}


def inverse_kinematics(x_mm, y_mm, L1_mm, L2_mm, elbow: int = 1):
    """Joint angles (deg) that put the end effector at (x, y) mm, nominal Eq. (3).

    ``elbow=+1`` gives θ2 ≥ 0, ``-1`` gives θ2 ≤ 0. Raises ValueError naming the
    first unreachable row (0-based).
    """
    x = np.atleast_1d(np.asarray(x_mm, dtype=float))
    y = np.atleast_1d(np.asarray(y_mm, dtype=float))
    c2 = (x**2 + y**2 - L1_mm**2 - L2_mm**2) / (2 * L1_mm * L2_mm)
    bad = np.flatnonzero(~(np.abs(c2) <= 1 + 1e-12))
    if bad.size:
        k = bad[0]
        raise ValueError(f"target row {k} ({x[k]:g}, {y[k]:g}) mm is outside the reach "
                         f"[{abs(L1_mm - L2_mm):g}, {L1_mm + L2_mm:g}] mm")
    t2 = elbow * np.arccos(np.clip(c2, -1, 1))
    t1 = np.arctan2(y, x) - np.arctan2(L2_mm * np.sin(t2), L1_mm + L2_mm * np.cos(t2))
    t1 = (t1 + np.pi) % (2 * np.pi) - np.pi
    return t1 / DEG, t2 / DEG


#: Most XY points of a workspace grid (a 1000 x 1000 square: ~0.6 mm steps over the paper robot's reach);
#: a finer step is a slip that would allocate gigabytes, refused before allocating.
MAX_WORKSPACE_POINTS = 1_000_000


def workspace_grid(L1_mm, L2_mm, theta1_range_deg, theta2_range_deg, step_mm: float, option: str = "step_mm"):
    """The XY grid points (step mm) the arm reaches with commands inside the given angle ranges.

    Inverse of Eq. (3) of 000 with either elbow (elbow +1 preferred where both
    fit). Returns (axis_mm (n,), inside (n, n) bool indexed [iy, ix],
    theta1_deg, theta2_deg of the inside points in row-major order). At most
    :data:`MAX_WORKSPACE_POINTS` grid points; errors name ``option`` (the step's parameter).
    """
    if not (np.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"workspace {option} must be finite and > 0, got {step_mm!r}")
    (a1, b1), (a2, b2) = (sorted((float(np.min(r)), float(np.max(r)))) for r in (theta1_range_deg, theta2_range_deg))
    reach = L1_mm + L2_mm
    if (2 * reach / step_mm + 1) ** 2 > MAX_WORKSPACE_POINTS:
        raise ValueError(f"{option} {step_mm:g} mm gives {(2 * reach / step_mm + 1) ** 2:.3g} workspace grid points "
                         f"over the {reach:g} mm reach, more than {MAX_WORKSPACE_POINTS:,} (use a coarser step)")
    n = int(np.floor(reach / step_mm))
    axis = step_mm * np.arange(-n, n + 1)
    X, Y = np.meshgrid(axis, axis)
    r = np.hypot(X, Y)
    ok = (r >= abs(L1_mm - L2_mm)) & (r <= reach)
    t1, t2 = np.full(X.shape, np.nan), np.full(X.shape, np.nan)
    tol = 1e-9
    for elbow in (-1, 1):  # +1 last: it wins where both elbows fit
        s1, s2 = np.full(X.shape, np.nan), np.full(X.shape, np.nan)
        s1[ok], s2[ok] = inverse_kinematics(X[ok], Y[ok], L1_mm, L2_mm, elbow=elbow)
        with np.errstate(invalid="ignore"):
            fit = (s1 >= a1 - tol) & (s1 <= b1 + tol) & (s2 >= a2 - tol) & (s2 <= b2 + tol)
        t1[fit], t2[fit] = np.clip(s1[fit], a1, b1), np.clip(s2[fit], a2, b2)
    inside = np.isfinite(t1)
    return axis, inside, t1[inside], t2[inside]


@dataclass(frozen=True)
class ScaraModel:
    """Robot part of the D-H model (Eq. 4) or of the error-map model (Eq. 6) of 000.

    * D-H: ``L1_mm``, ``L2_mm``, ``theta20_deg``; maps are None.
    * Error map: ``L1_mm``, ``L2_mm`` and maps for J1 and J2 (θ20 absorbed in
      the J2 map, so ``theta20_deg`` is None).
    * ``bidirectional=False`` (error map of a campaign without direction columns): each map has a single
      branch, its forward values (the reverse values mirror them), parameters ``Jn_forward_deg[i]`` only,
      and directions are ignored -- no backlash identified (as :class:`olti_drake.model.serial.JointMap`).

    The parameter vector (:meth:`parameter_names`) is ordered as in Eq. (4)/(6):
    lengths mm, angles deg.
    """

    L1_mm: float = PAPER_L1_MM
    L2_mm: float = PAPER_L2_MM
    theta20_deg: Optional[float] = 0.0
    map1: Optional[ErrorMap] = None
    map2: Optional[ErrorMap] = None
    bidirectional: bool = True

    def __post_init__(self):
        if (self.map1 is None) != (self.map2 is None):
            raise ValueError("error-map model needs maps for both J1 and J2")
        if self.map1 is not None and self.theta20_deg is not None:
            raise ValueError("error-map model absorbs theta20 in the J2 map: set theta20_deg=None")

    @property
    def is_errormap(self) -> bool:
        return self.map1 is not None

    def parameter_names(self) -> list[str]:
        """Names of the robot parameters, e.g. ``L1_mm``, ``J2_reverse_deg[3]``."""
        names = ["L1_mm", "L2_mm"]
        if not self.is_errormap:
            return names + ["theta20_deg"]
        for axis, m in (("J1", self.map1), ("J2", self.map2)):
            for block in self.branches:
                names += [f"{axis}_{block}_deg[{i}]" for i in range(m.n_nodes)]
        return names

    @property
    def branches(self) -> tuple:
        """The map branches identified: ("forward", "reverse"), or ("forward",) for a one-directional model."""
        return ("forward", "reverse") if self.bidirectional else ("forward",)

    def map_values(self, m: ErrorMap) -> np.ndarray:
        """A map's parameters: [forward..., reverse...], or the forward values of a one-directional model."""
        return m.values if self.bidirectional else m.forward_deg.copy()

    def parameter_vector(self) -> np.ndarray:
        head = [self.L1_mm, self.L2_mm]
        if not self.is_errormap:
            return np.array(head + [self.theta20_deg])
        return np.concatenate([head, self.map_values(self.map1), self.map_values(self.map2)])

    def with_parameters(self, x) -> "ScaraModel":
        """A copy with the parameter vector ``x`` (same layout as :meth:`parameter_names`)."""
        x = np.asarray(x, dtype=float)
        if x.size != len(self.parameter_names()):
            raise ValueError(f"expected {len(self.parameter_names())} parameters, got {x.size}")
        if not self.is_errormap:
            return ScaraModel(float(x[0]), float(x[1]), float(x[2]))
        n1 = len(self.branches) * self.map1.n_nodes
        v1, v2 = x[2:2 + n1], x[2 + n1:]
        if not self.bidirectional:  # one branch: the reverse values mirror the forward ones
            v1, v2 = np.concatenate([v1, v1]), np.concatenate([v2, v2])
        return ScaraModel(float(x[0]), float(x[1]), None, self.map1.with_values(v1), self.map2.with_values(v2),
                          self.bidirectional)

    def map_dict(self, m: ErrorMap) -> dict:
        """A map's ``error_map.Jn`` object (formats.md); a one-directional map has ``forward_deg`` only."""
        out = m.to_dict()
        if not self.bidirectional:
            out.pop("reverse_deg")
        return out

    def positions(self, cmd: JointCommands) -> np.ndarray:
        """Predicted actual end-effector positions (N, 2) mm (Eq. 3 with Eq. 7)."""
        return self.jacobian_rows(cmd)[0]

    def interpolation(self, cmd: JointCommands):
        """The maps' bracketing nodes and weights of every command (Eq. 8-9 of 000,
        :meth:`ErrorMap.interpolation`): (c1, w1, c2, w2), each (N, 2); None for the D-H
        model. They depend on the grids only, not on the node values: :meth:`jacobian_rows`
        takes them precomputed."""
        if not self.is_errormap:
            return None
        if not self.bidirectional:  # one branch (block 0..n-1): the directions are ignored
            return (*self.map1.interpolation(cmd.theta1_deg, 1.0), *self.map2.interpolation(cmd.theta2_deg, 1.0))
        if getattr(cmd, "one_directional", False):
            raise ValueError("approach directions (dir1, dir2) are needed: the error maps are bidirectional")
        return (*self.map1.interpolation(cmd.theta1_deg, cmd.dir1), *self.map2.interpolation(cmd.theta2_deg, cmd.dir2))

    def jacobian_rows(self, cmd: JointCommands, X=None, interpolation=None):
        """Positions and the Jacobian in row-compressed form (Eq. 3 with Eq. 7-9 of 000).

        Every row has the same few non-zeros: L1, L2 and θ20 (D-H), or L1, L2
        and the two bracketing nodes of each map (error map).

        Args:
            cmd: N commands.
            X: optional (T, P) parameter vectors (layout of :meth:`parameter_names`)
                evaluated at once -- the grid, hence the interpolation, is shared;
                default: this model's own parameters.
            interpolation: :meth:`interpolation` of ``cmd`` on this model's grids when at
                hand (error map; default computed).

        Returns:
            p (N, 2) mm; cols (N, m) parameter indices; dx, dy (N, m) the
            matching entries of dx/dparams and dy/dparams (mm/mm, mm/deg).
            With X: p, dx, dy get a leading trial axis (T, ...).
        """
        batch = X is not None
        X = np.atleast_2d(self.parameter_vector() if X is None else np.asarray(X, dtype=float))
        n = len(cmd)
        L1, L2 = X[:, :1, None], X[:, 1:2, None]
        if not self.is_errormap:
            t1 = np.broadcast_to(cmd.theta1_deg, (len(X), n))
            p, dp = forward_kinematics(t1, cmd.theta2_deg + X[:, 2:3], L1, L2)
            cols = np.broadcast_to(np.arange(3), (n, 3))
            d = [np.stack(np.broadcast_arrays(dp["L1"][..., c], dp["L2"][..., c], dp["theta2"][..., c]), -1)
                 for c in (0, 1)]
        else:
            c1, w1, c2, w2 = self.interpolation(cmd) if interpolation is None else interpolation
            off2 = 2 + len(self.branches) * self.map1.n_nodes
            # Eq. (7), the two bracketing nodes summed as np.sum(w * X[:, cols], axis=-1) would, ~3x faster.
            t1 = cmd.theta1_deg + (w1[:, 0] * X[:, 2 + c1[:, 0]] + w1[:, 1] * X[:, 2 + c1[:, 1]])
            t2 = cmd.theta2_deg + (w2[:, 0] * X[:, off2 + c2[:, 0]] + w2[:, 1] * X[:, off2 + c2[:, 1]])
            p, dp = forward_kinematics(t1, t2, L1, L2)
            cols = np.column_stack([np.zeros(n, int), np.ones(n, int), 2 + c1, off2 + c2])
            d = [np.concatenate([dp["L1"][..., c:c + 1], dp["L2"][..., c:c + 1], dp["theta1"][..., c:c + 1] * w1,
                                 dp["theta2"][..., c:c + 1] * w2], axis=-1) for c in (0, 1)]
        if batch:
            return p, cols, d[0], d[1]
        return p[0], cols, d[0][0], d[1][0]

    def positions_batch(self, cmd: JointCommands, X) -> np.ndarray:
        """Positions (T, N, 2) mm for T parameter vectors X (T, P) at once (Eq. 3 with Eq. 7)."""
        return self.jacobian_rows(cmd, X)[0]

    def positions_and_jacobian(self, cmd: JointCommands):
        """Positions (N, 2) mm and sparse Jacobians d x/d params, d y/d params.

        Returns ``(p, Jx, Jy)``; Jx, Jy are CSR (N, P) in the units of
        :meth:`parameter_names` (mm/mm, mm/deg). Analytic: Eq. (3) chain-ruled
        through the interpolation weights of Eq. (7)-(9).
        """
        p, cols, dx, dy = self.jacobian_rows(cmd)
        return p, rows_to_csr(cols, dx, len(self.parameter_names())), rows_to_csr(cols, dy, len(self.parameter_names()))


def rows_to_csr(cols, values, n_cols: int) -> sp.csr_matrix:
    """CSR matrix from a row-compressed (N, m) column/value layout (duplicates add up)."""
    n, m = values.shape
    return sp.csr_matrix((values.ravel(), np.asarray(cols).ravel(), np.arange(0, n * m + 1, m)), shape=(n, n_cols))


@dataclass(frozen=True, eq=False)
class ScaraJacobian:
    """∂p/∂x of the SCARA's N poses (000 Eq. 3 with Eq. 7-9), row-compressed: pose k's x and y depend on the
    parameter columns ``cols[k]`` (N, m) with the entries ``dx[k]``, ``dy[k]`` (N, m; mm/mm on the lengths,
    mm/deg on θ20 and the map nodes), over ``n_params`` columns. The sparse conventions of the other position
    models (:class:`olti_drake.model.free_points.FreePointJacobian`,
    :class:`olti_drake.model.serial.PositionJacobian`): :meth:`tocsr` rows x, y of pose 0, then pose 1, ...;
    :meth:`contract` for distance rows; :meth:`take`."""

    cols: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    n_params: int

    def tocsr(self, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """The (2N, n_cols) sparse Jacobian, rows x, y of pose 0, then pose 1, ..., plus per-row extra entries
        (``extra_vals``/``extra_cols`` (2N, e): a measurement's own parameters, columns ≥ n_params)."""
        n, m = self.cols.shape
        cols = np.repeat(self.cols, 2, axis=0)
        vals = np.stack([self.dx, self.dy], axis=1).reshape(2 * n, m)
        if extra_vals is not None:
            cols, vals = np.hstack([cols, extra_cols]), np.hstack([vals, extra_vals])
        return rows_to_csr(cols, vals, n_cols or self.n_params)

    def contract(self, u, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """(N, n_cols) sparse rows u_k · ∂p_k/∂x (u (N, 2)), plus per-row extra entries (a measurement's own
        parameters, columns ≥ n_params)."""
        u = np.asarray(u, dtype=float)
        cols, vals = self.cols, u[:, :1] * self.dx + u[:, 1:2] * self.dy
        if extra_vals is not None:
            cols, vals = np.hstack([cols, extra_cols]), np.hstack([vals, extra_vals])
        return rows_to_csr(cols, vals, n_cols or self.n_params)

    def take(self, index) -> "ScaraJacobian":
        """The Jacobian of the poses ``index`` (e.g. the pose of every reading)."""
        return ScaraJacobian(self.cols[index], self.dx[index], self.dy[index], self.n_params)


class ScaraPositionModel:
    """The SCARA closed form of 000 as a position model: the end-effector position p̂ (mm) of N commanded poses
    (θ1*, θ2*, approach directions) by Eq. (3), through the D-H offset θ20 (Eq. 4) or the bidirectional error
    maps (Eq. 7-9) of ``robot`` -- the fast path of the SCARA identification and the oracle of the general chain
    (:mod:`olti_drake.model.chain`).

    Parameters x (``names``): :meth:`ScaraModel.parameter_names` (``L1_mm``, ``L2_mm``, ``theta20_deg`` or the map
    nodes ``J1_forward_deg[i]``, ...), mm and deg; the start is ``robot``'s values. 2D points (``dim`` = 2): read by
    :class:`olti_drake.model.measurements.StationDistanceMeasurement` from the reflectors P_j (000 Eq. 5 / 10).

    ``robot`` also gives the grids and the nominal link lengths of :meth:`implausible` (its own L1, L2: the start).
    """

    dim = 2
    #: A link length outside [1/f, f] x its nominal value is physically impossible: the start or the units are wrong.
    LENGTH_FACTOR = 2.0
    #: A joint deviation (map node, θ20) beyond this is no positioning deviation, deg.
    MAX_DEVIATION_DEG = 10.0

    def __init__(self, robot: ScaraModel, commands: JointCommands):
        self.robot = robot
        self.commands = commands
        self.names = tuple(robot.parameter_names())
        #: 0 .. N − 1: the ``points`` of readings taken one per pose, in order (:meth:`rows` then indexes nothing).
        self.all_poses = np.arange(len(commands))
        self._interpolation = None  # the maps' weights of the commands (Eq. 8-9): fixed, computed on first use

    def _rows(self, X):
        """:meth:`ScaraModel.jacobian_rows` of the commands at X (T, n_params), the interpolation computed once."""
        if self._interpolation is None and self.robot.is_errormap:
            self._interpolation = self.robot.interpolation(self.commands)
        return self.robot.jacobian_rows(self.commands, X, self._interpolation)

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_points(self) -> int:
        return len(self.commands)

    def start_vector(self) -> np.ndarray:
        """The robot's parameters (``names`` order; mm, deg)."""
        return self.robot.parameter_vector()

    def _X(self, x):
        x = self.start_vector() if x is None else np.asarray(x, dtype=float)
        if x.shape != (self.n_params,):
            raise ValueError(f"parameter vector: {x.size} values, the model has {self.n_params}")
        return x[None]

    def positions(self, x=None) -> np.ndarray:
        """The poses' end-effector positions (N, 2) mm at x (default the start), Eq. (3) with Eq. (7)."""
        return self._rows(self._X(x))[0][0]

    def jacobian(self, x=None):
        """The positions (N, 2) mm at x (default the start) and their :class:`ScaraJacobian` over ``names``
        (analytic: Eq. (3) chain-ruled through the interpolation weights of Eq. (7)-(9))."""
        p, cols, dx, dy = self._rows(self._X(x))
        return p[0], ScaraJacobian(cols, dx[0], dy[0], self.n_params)

    def rows(self, X, points):
        """The positions read, batched, row-compressed (for :func:`~olti_drake.model.measurements.distance_rows_nd`).

        Args:
            X: (T, n ≥ n_params) parameter vectors (the model's first), mm and deg.
            points: (K,) the pose of every reading (index into the commands).

        Returns:
            p (T, K, 2) mm; cols (K, m) the parameter columns of pose ``points[k]`` (L1, L2 and θ20, or L1, L2 and
            the two bracketing nodes of each map); (dpx, dpy) the matching (T, K, m) ∂p_x, ∂p_y (mm/mm, mm/deg).
        """
        p, cols, dx, dy = self._rows(X[:, :self.n_params])
        if not (points is self.all_poses or np.array_equal(points, self.all_poses)):  # a reading per pose, in order
            p, cols, dx, dy = p[:, points], cols[points], dx[:, points], dy[:, points]
        return p, cols, (dx, dy)

    def roughness(self):
        """Roughness rows over ``names`` of the J1 and J2 maps (:meth:`~olti_drake.model.errormap.ErrorMap.roughness`:
        both branches and the backlash, or the single branch), for the smoothness prior; None for ``dh``."""
        if not self.robot.is_errormap:
            return None
        import scipy.sparse as sp

        blocks, start = [], 2
        for m in (self.robot.map1, self.robot.map2):
            R = m.roughness(self.robot.bidirectional)
            width = m.n_nodes * len(self.robot.branches)
            R = R[:, :width]
            blocks.append(sp.hstack([sp.csr_matrix((R.shape[0], start)), R,
                                     sp.csr_matrix((R.shape[0], self.n_params - start - width))]))
            start += width
        R = sp.vstack(blocks, format="csr")
        return R if R.shape[0] else None

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values or uncertainties) in result.json's keys (formats.md): ``L1_mm``,
        ``L2_mm``, then ``theta20_deg`` or ``error_map`` (its ``grid_deg`` only with values)."""
        m = self.robot.with_parameters(v)
        out = {"L1_mm": float(m.L1_mm), "L2_mm": float(m.L2_mm)}
        if not m.is_errormap:
            out["theta20_deg"] = float(m.theta20_deg)
            return out
        out["error_map"] = {"J1": m.map_dict(m.map1), "J2": m.map_dict(m.map2)}
        if uncertainty:
            for axis in out["error_map"].values():
                axis.pop("grid_deg")
        return out

    def implausible(self, x) -> list:
        """Link lengths not positive or outside [1/f, f] x nominal (f = :attr:`LENGTH_FACTOR`, the nominal: the
        robot's start); joint deviations (θ20, map nodes) beyond :attr:`MAX_DEVIATION_DEG`; one phrase each."""
        x = np.asarray(x, dtype=float)
        out = []
        for i, (name, nominal) in enumerate((("L1", self.robot.L1_mm), ("L2", self.robot.L2_mm))):
            v = x[i]
            if not v > 0:
                out.append(f"{name} = {v:.6g} mm is not a positive length")
            elif nominal > 0 and not nominal / self.LENGTH_FACTOR <= v <= nominal * self.LENGTH_FACTOR:
                out.append(f"{name} = {v:.6g} mm is more than {self.LENGTH_FACTOR:g} x off its nominal "
                           f"{nominal:g} mm (readings in mm? the right --nominal-mm?)")
        dev = np.abs(x[2:self.n_params])
        if dev.size and dev.max() > self.MAX_DEVIATION_DEG:
            i = 2 + int(np.argmax(dev))
            out.append(f"{self.names[i]} = {x[i]:.6g} deg is beyond {self.MAX_DEVIATION_DEG:g} deg, no positioning "
                       f"deviation")
        return out

# ----------------------------------------------------------------------------- the simulated truth
Deviation = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TrueRobot:
    """True link lengths (mm), joint deviations Δθ(θ*, dir) (deg) and laser mount.

    ``deviations`` maps "J1", "J2", "J4" to deviation callables (missing =
    perfect axis). The J2 deviation includes the offset θ20. The laser beam
    leaves the point ``beam_offset_mm`` = (along, lateral) of the J4 frame
    rotated by θ40, along that frame's x axis.
    """

    L1_mm: float
    L2_mm: float
    deviations: Dict[str, Deviation] = field(default_factory=dict)
    theta40_deg: float = 0.0
    beam_offset_mm: tuple = (0.0, 0.0)

    def deviation(self, axis: str) -> Deviation:
        return self.deviations.get(axis) or NoDeviation()

    def actual_angles(self, axis: str, theta_cmd_deg, direction):
        """θ = θ* + Δθ(θ*, dir) for one axis, deg (Eq. (7) of 000)."""
        th = np.asarray(theta_cmd_deg, dtype=float)
        return th + self.deviation(axis)(th, direction)

    def end_effector(self, theta1_cmd_deg, theta2_cmd_deg, dir1, dir2):
        """Actual J4-axis position (N, 2) mm for commanded J1/J2 angles and directions."""
        t1 = self.actual_angles("J1", theta1_cmd_deg, dir1)
        t2 = self.actual_angles("J2", theta2_cmd_deg, dir2)
        return forward_kinematics(t1, t2, self.L1_mm, self.L2_mm)[0]

    def laser_beam(self, theta1_cmd_deg, theta2_cmd_deg, theta4_cmd_deg, dir1, dir2, dir4):
        """Actual beam origin (N, 2) mm and world beam angle (N,) deg.

        The beam angle is θ1 + θ2 + θ4 + θ40 of the *actual* angles: open-loop
        steering misses the reflector by the joint deviations (000 §5).
        """
        t1 = self.actual_angles("J1", theta1_cmd_deg, dir1)
        t2 = self.actual_angles("J2", theta2_cmd_deg, dir2)
        t4 = self.actual_angles("J4", theta4_cmd_deg, dir4)
        p = forward_kinematics(t1, t2, self.L1_mm, self.L2_mm)[0]
        angle = t1 + t2 + t4 + self.theta40_deg
        a = np.radians(angle)
        da, de = self.beam_offset_mm
        origin = p + np.stack([da * np.cos(a) - de * np.sin(a), da * np.sin(a) + de * np.cos(a)], -1)
        return origin, angle
