"""Position model of a serial robot in 3D, and what distances and tracker points see of it.

The model layer of "any serial robot in 3D" (no solver here):

* :class:`JointMap` — the bidirectional angular positioning deviation of one
  joint, 000 Eq. (6)–(9), on :class:`olti_drake.model.errormap.ErrorMap`; a
  one-directional map (files without ``dir`` columns) has a single branch.
* :class:`SerialPositionModel` — the chain of :mod:`olti_drake.model.chain`
  with its free location errors (the identifiable base set), per-joint angle
  offsets (``dh``) or error maps (``errormap``: each map's level absorbs the
  joint's zero offset, as θ20 is absorbed in 000's J2 map) and the tool-point
  offset: tool point p (M, 3) and ∂p/∂x as a scipy.sparse matrix, the map
  columns sparse (each reading touches ≤ 2 nodes per joint, Eq. (7) weights).
* Measurement models on top: :class:`DistanceMeasurement` (stations P_j and
  dead paths d0_j, r = ‖p − P_j‖ − d0_j − d, 000 Eq. (10) in 3D, 001 Eq. (3);
  the residual is :func:`olti_drake.model.measurements.distance_residual`),
  :class:`PointMeasurement` (tracker points in an unknown rigid frame,
  r = R·p + t − m) and :class:`RootPositionMeasurement` (points in the root
  frame, for analysis).
* :func:`find_gauge` — what the readings cannot see (the null space of the
  Jacobian at random poses, worked out numerically) as named linear
  constraints A x = b, each with the sentence saying what it fixes.
* :func:`synthetic_truth` / :func:`synthetic_campaign` — a seeded continuous
  truth (harmonic joint deviations with backlash, joint-frame location
  errors, a tool offset off the last axis, stations, a tracker frame) and its
  readings, for tests and benchmarks.

Units: mm and degrees in every parameter, reading, residual and Jacobian
(mm/mm, mm/deg). Frame: the chain's root frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import scipy.sparse as sp

from olti_drake.model.errormap import ErrorMap, Harmonic, HarmonicDeviation, approach_directions
from olti_drake.model.chain import (DEG, FRAME_NAMES, GEOMETRIC_SUFFIXES, PLANAR_REASON, TOOL_NAMES,
                                    UNLIMITED_RANGE_DEG, SerialChain, base_parameter_set, plane_frame, _cross)
from olti_drake.model.frames import XYZ_CONVENTION, into_frame, out_of_frame, turn_rows, xyz_rotation
from olti_drake.model.measurements import distance_residual, lengths

MODEL_KINDS = ("dh", "errormap")
#: Relative singular value below which a parameter combination counts as unseen (gauge analysis).
NULL_RTOL = 1e-9


# ------------------------------------------------------------------------ maps
def grid_every(step_deg: float, lo_deg: float, hi_deg: float) -> np.ndarray:
    """Map nodes every ``step_deg`` covering [lo, hi] deg: the multiples of the step from
    floor(lo/S)·S to ceil(hi/S)·S (one node when the joint never moves off a multiple)."""
    step = float(step_deg)
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"grid step: must be a positive number of degrees, got {step_deg!r}")
    if not (np.isfinite(lo_deg) and np.isfinite(hi_deg) and lo_deg <= hi_deg):
        raise ValueError(f"grid range: [{lo_deg}, {hi_deg}] deg is not a finite range")
    first = np.floor(lo_deg / step + 1e-9)
    last = np.ceil(hi_deg / step - 1e-9)
    return step * np.arange(first, max(first, last) + 1)


@dataclass(frozen=True, eq=False)
class JointMap:
    """Δθ_i(θ*_i, dir_i) of one joint (000 Eq. (6)–(9)), deg, as an :class:`ErrorMap`.

    ``bidirectional=False`` is the single-branch map of a file without
    direction columns: its values are the forward branch only (the reverse
    branch of ``emap`` mirrors it) and directions are ignored.
    """

    emap: ErrorMap
    bidirectional: bool = True

    @classmethod
    def zeros(cls, joint: str, grid_deg, bidirectional: bool = True) -> "JointMap":
        g = np.asarray(grid_deg, float)
        return cls(ErrorMap(g, np.zeros(g.size), np.zeros(g.size), axis=joint), bidirectional)

    @property
    def joint(self) -> str:
        return self.emap.axis

    @property
    def n_values(self) -> int:
        return self.emap.n_nodes * (2 if self.bidirectional else 1)

    def names(self) -> Tuple[str, ...]:
        """``<joint>_forward_deg[i]`` then (bidirectional) ``<joint>_reverse_deg[i]``."""
        branches = ("forward", "reverse") if self.bidirectional else ("forward",)
        return tuple(f"{self.joint}_{b}_deg[{i}]" for b in branches for i in range(self.emap.n_nodes))

    @property
    def values(self) -> np.ndarray:
        return self.emap.values if self.bidirectional else self.emap.forward_deg.copy()

    def with_values(self, values) -> "JointMap":
        v = np.asarray(values, float)
        if v.shape != (self.n_values,):
            raise ValueError(f"error map {self.joint}: {v.size} values, expected {self.n_values}")
        full = v if self.bidirectional else np.concatenate([v, v])
        return JointMap(self.emap.with_values(full), self.bidirectional)

    def interpolation(self, theta_deg, direction):
        """(cols, w), each (K, 2): Δθ = Σ w · values[cols] (Eq. (7)–(9)); cols index ``values``."""
        d = 1.0 if (direction is None or not self.bidirectional) else direction
        return self.emap.interpolation(theta_deg, d)

    def __call__(self, theta_deg, direction=None) -> np.ndarray:
        cols, w = self.interpolation(theta_deg, direction)
        return np.sum(w * self.values[cols], axis=1)

    def roughness(self) -> sp.csr_matrix:
        """Roughness rows on ``values`` (:meth:`ErrorMap.roughness`: both branches and the backlash, or the single
        branch), deg²/deg³."""
        R = self.emap.roughness(self.bidirectional)
        return R if self.bidirectional else R[:, :self.emap.n_nodes]

    def level_row(self) -> Tuple[np.ndarray, float]:
        """(row, at): the map's level at the node-clipped command 0 deg as a row on ``values``:
        (Δθ(at, +1) + Δθ(at, −1))/2, or Δθ(at) for a single branch — as the SCARA's J1 gauge."""
        g = self.emap.grid_deg
        at = float(np.clip(0.0, g[0], g[-1]))
        dirs = [1.0, -1.0] if self.bidirectional else [1.0]
        cols, w = self.interpolation(np.full(len(dirs), at), np.array(dirs))
        row = np.zeros(self.n_values)
        np.add.at(row, cols.ravel(), w.ravel() / len(dirs))
        return row, at

    def to_dict(self) -> dict:
        """The ``error_map.<joint>`` object of result.json (formats.md): ``forward_deg`` only
        for a one-directional map."""
        out = self.emap.to_dict()
        if not self.bidirectional:
            del out["reverse_deg"]
        return out


# ----------------------------------------------------------------- the model
@dataclass(frozen=True, eq=False)
class PositionJacobian:
    """∂p/∂x of M tool points: ``dense`` (M, 3, D) for the first D parameters (geometric,
    tool, offsets), and per error map (start column, joint, cols (M, 2), w (M, 2)) with the
    joint-angle column ``angle[:, :, joint]`` (mm/deg): column start + cols[k, c] of reading
    k is angle[k, :, joint] · w[k, c] (000 Eq. (7): the model is linear in the node values)."""

    dense: np.ndarray
    angle: np.ndarray
    maps: Tuple[tuple, ...]
    n_params: int

    def tocsr(self, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """The (3M, n_cols) sparse Jacobian, rows x, y, z of reading 0, then reading 1, ...,
        plus per-row extra entries (measurement parameters: columns ≥ P)."""
        m = self.dense.shape[0]
        map_vals = [(self.angle[:, :, j][:, :, None] * w[:, None, :]).reshape(3 * m, 2)
                    for _, j, _, w in self.maps]
        map_cols = [np.repeat(start + cols, 3, axis=0) for start, _, cols, _ in self.maps]
        return _rows_csr(self.dense.reshape(3 * m, -1), map_vals, map_cols, extra_vals, extra_cols,
                         n_cols or self.n_params)

    def contract(self, u, extra_vals=None, extra_cols=None, n_cols=None) -> sp.csr_matrix:
        """(M, n_cols) sparse rows u_k · ∂p_k/∂x, plus per-row extra entries (measurement
        parameters: columns ≥ P)."""
        dense = np.einsum("mc,mcd->md", u, self.dense)
        map_vals = [np.einsum("mc,mc->m", u, self.angle[:, :, j])[:, None] * w
                    for _, j, _, w in self.maps]
        map_cols = [start + cols for start, _, cols, _ in self.maps]
        return _rows_csr(dense, map_vals, map_cols, extra_vals, extra_cols, n_cols or self.n_params)

    def take(self, index) -> "PositionJacobian":
        """The Jacobian of the points ``index`` (rows of readings that repeat a pose)."""
        return PositionJacobian(self.dense[index], self.angle[index],
                                tuple((s, j, c[index], w[index]) for s, j, c, w in self.maps), self.n_params)

    def rotated(self, rot) -> "PositionJacobian":
        """The Jacobian of R·p for a constant rotation R (3×3)."""
        return PositionJacobian(np.einsum("ij,mjd->mid", rot, self.dense),
                                np.einsum("ij,mjd->mid", rot, self.angle), self.maps, self.n_params)


def _rows_csr(dense, map_vals, map_cols, extra_vals, extra_cols, n_cols) -> sp.csr_matrix:
    """A CSR matrix whose every row has the same pattern: D dense columns 0..D-1, 2 entries
    per map, k extra entries — assembled without COO sorting (columns already ascending)."""
    rows, d = dense.shape
    vals = [dense] + list(map_vals) + ([extra_vals] if extra_vals is not None else [])
    cols = [np.broadcast_to(np.arange(d), (rows, d))] + list(map_cols)
    cols += [extra_cols] if extra_cols is not None else []
    data = np.hstack(vals)
    index = np.hstack(cols).astype(np.int32 if n_cols < 2 ** 31 else np.int64)
    width = data.shape[1]
    jac = sp.csr_matrix((data.ravel(), index.ravel(), np.arange(rows + 1) * width),
                        shape=(rows, n_cols))
    jac.sum_duplicates()  # a one-node map puts both weights on the same column
    return jac


class SerialPositionModel:
    """The tool point of a serial chain with its identifiable errors (mm, deg).

    Parameters x, in this order (``names``):

    1. the free location errors of the joint frames (``<joint>_dx_mm`` …
       ``<joint>_drz_deg``, chain order; the others are held at the values of
       ``chain_params``);
    2. the tool-point offset ``tool_x_mm, tool_y_mm, tool_z_mm`` (tool frame);
    3. ``dh``: a constant angle offset ``<joint>_offset_deg`` per joint that has
       one; then, with compliance, ``<joint>_compliance_deg_per_Nm`` per joint
       with a gravity torque;
    4. ``errormap``: the map values ``<joint>_forward_deg[i]`` (and
       ``<joint>_reverse_deg[i]``) per joint with a map, chain order. The map
       level absorbs the joint's zero offset, so ``errormap`` has no offsets.

    The actual joint angle is θ_i = θ*_i + offset_i (``dh``) or θ*_i +
    Δθ_i(θ*_i, dir_i) (``errormap``, 000 Eq. (7)), plus c_i·τ_i(θ*) for a
    compliant joint (τ_i the torque gravity applies about it at the commanded
    pose, N·m, :func:`~olti_drake.model.chain.gravity_torques`; c_i deg/(N·m));
    p = chain FK at θ.
    ``dropped`` pairs each parameter left out with the reason.
    """

    def __init__(self, chain: SerialChain, kind: str, geometric: Sequence[str],
                 chain_params=None, offsets: Sequence[str] = (), maps: Sequence[JointMap] = (),
                 dropped: Sequence[Tuple[str, str]] = (), offset_values=None,
                 compliance: Sequence[str] = (), compliance_values=None, held_tool: Sequence[str] = ()):
        if kind not in MODEL_KINDS:
            raise ValueError(f"model: 'dh' or 'errormap', not {kind!r}")
        self.chain, self.kind = chain, kind
        n = chain.n_joints
        all_names = chain.parameter_names()
        self.chain_params = (chain.nominal_parameters() if chain_params is None
                             else np.asarray(chain_params, float).copy())
        unknown = [g for g in geometric if g not in all_names[:6 * n]]
        if unknown:
            raise ValueError(f"geometric parameter '{unknown[0]}' is not a location error of the chain")
        geo = sorted(all_names.index(g) for g in geometric)
        bad = [t for t in held_tool if t not in TOOL_NAMES]
        if bad:
            raise ValueError(f"held tool coordinate '{bad[0]}' is not one of {', '.join(TOOL_NAMES)}")
        # A planar robot's tool offset along the plane's normal is held (chain_params), not identified.
        self.held_tool = tuple(t for t in TOOL_NAMES if t in held_tool)
        self._tool_cols = [6 * n + k for k, t in enumerate(TOOL_NAMES) if t not in self.held_tool]
        self._chain_cols = np.array(geo + self._tool_cols, dtype=int)
        joints = list(chain.joint_names)
        self.offset_joints = np.array(sorted(joints.index(j) for j in offsets), dtype=int)
        self.offset_values = (np.zeros(len(self.offset_joints)) if offset_values is None
                              else np.asarray(offset_values, float).reshape(len(self.offset_joints)))
        self.compliance_joints = np.array(sorted(joints.index(j) for j in compliance), dtype=int)
        self.compliance_values = (np.zeros(len(self.compliance_joints)) if compliance_values is None
                                  else np.asarray(compliance_values, float).reshape(len(self.compliance_joints)))
        self._torques = {}  # gravity torques per commands array (by content): Drake is called once per campaign
        self.maps = tuple(sorted(maps, key=lambda m: joints.index(m.joint)))
        if kind == "dh" and self.maps or kind == "errormap" and len(self.offset_joints):
            raise ValueError(f"model {kind}: offsets belong to 'dh', maps to 'errormap'")
        self.map_joints = np.array([joints.index(m.joint) for m in self.maps], dtype=int)
        names = [all_names[c] for c in self._chain_cols]
        names += [f"{joints[j]}_offset_deg" for j in self.offset_joints]
        names += [f"{joints[j]}_compliance_deg_per_Nm" for j in self.compliance_joints]
        self.n_dense = len(names)
        self.map_starts = []
        for m in self.maps:
            self.map_starts.append(len(names))
            names += m.names()
        self.names = tuple(names)
        self.dropped = tuple(dropped)
        #: Built with a planar robot's reduction (readings in its plane: out-of-plane parameters held).
        self.planar_reduced = any(why.startswith(PLANAR_REASON) for _, why in self.dropped)

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def geometric_names(self) -> Tuple[str, ...]:
        """The free location errors (the first block of ``names``)."""
        return self.names[:len(self._chain_cols) - len(self._tool_cols)]

    @property
    def bidirectional(self) -> bool:
        return any(m.bidirectional for m in self.maps)

    # ------------------------------------------------------------ vectors
    def start_vector(self) -> np.ndarray:
        """x at ``chain_params``, ``offset_values`` and the maps' current values."""
        x = np.zeros(self.n_params)
        k = len(self._chain_cols)
        x[:k] = self.chain_params[self._chain_cols]
        x[k:self.n_dense] = np.concatenate([self.offset_values, self.compliance_values])
        for start, m in zip(self.map_starts, self.maps):
            x[start:start + m.n_values] = m.values
        return x

    def chain_parameters(self, x) -> np.ndarray:
        """The chain's 6N + 3 parameter vector for x (held values where not free)."""
        out = self.chain_params.copy()
        out[self._chain_cols] = np.asarray(x)[:len(self._chain_cols)]
        return out

    def with_vector(self, x) -> "SerialPositionModel":
        """A copy whose held values, start and map values are those of x."""
        x = self._check(x)
        maps = [m.with_values(x[s:s + m.n_values]) for s, m in zip(self.map_starts, self.maps)]
        joints = self.chain.joint_names
        return SerialPositionModel(self.chain, self.kind, self.geometric_names,
                                   self.chain_parameters(x), [joints[j] for j in self.offset_joints],
                                   maps, self.dropped, x[len(self._chain_cols):self._compliance_start],
                                   [joints[j] for j in self.compliance_joints], x[self._compliance_start:self.n_dense],
                                   self.held_tool)

    def _check(self, x):
        x = np.asarray(x, float)
        if x.shape != (self.n_params,):
            raise ValueError(f"parameter vector: {x.size} values, the model has {self.n_params}")
        return x

    # --------------------------------------------------------- kinematics
    def command_ranges(self) -> np.ndarray:
        """(N, 2) commanded range per joint, deg: the map's grid, else the joint limits
        (±``UNLIMITED_RANGE_DEG`` where unlimited)."""
        lo = np.where(np.isfinite(self.chain.lower_deg), self.chain.lower_deg, -UNLIMITED_RANGE_DEG)
        hi = np.where(np.isfinite(self.chain.upper_deg), self.chain.upper_deg, UNLIMITED_RANGE_DEG)
        out = np.column_stack([lo, hi])
        for j, m in zip(self.map_joints, self.maps):
            out[j] = m.emap.grid_deg[[0, -1]]
        return out

    def _commands(self, commands, dirs):
        th = np.atleast_2d(np.asarray(commands, float))
        if th.shape[1] != self.chain.n_joints:
            raise ValueError(f"commands: {th.shape[1]} joint columns, the chain has {self.chain.n_joints}")
        if dirs is not None:
            dirs = np.broadcast_to(np.asarray(dirs, float), th.shape)
        elif self.bidirectional:
            raise ValueError("approach directions (dir1..dirN) are needed: the error maps are bidirectional")
        return th, dirs

    def _interpolations(self, th, dirs):
        return [m.interpolation(th[:, j], None if dirs is None else dirs[:, j])
                for j, m in zip(self.map_joints, self.maps)]

    def actual_angles(self, commands, dirs=None, x=None) -> np.ndarray:
        """θ = θ* + offset (dh) or θ* + Δθ(θ*, dir) (errormap, 000 Eq. (7)), (M, N) deg."""
        th, dirs = self._commands(commands, dirs)
        return self._actual(th, self._interpolations(th, dirs), self._x(x))

    def _x(self, x):
        return self.start_vector() if x is None else self._check(x)

    @property
    def _compliance_start(self) -> int:
        return len(self._chain_cols) + len(self.offset_joints)

    def gravity_torques(self, th) -> np.ndarray:
        """(M, C) N·m about the compliant joints at commands ``th`` (M, N) deg (cached by content)."""
        if not len(self.compliance_joints):
            return np.zeros((len(th), 0))
        key = (th.shape, hash(th.tobytes()))
        if key not in self._torques:
            from olti_drake.model.chain import gravity_torques

            if len(self._torques) > 8:
                self._torques.clear()
            self._torques[key] = gravity_torques(self.chain, th)[:, self.compliance_joints]
        return self._torques[key]

    def _actual(self, th, interps, x):
        out = th.copy()
        k = len(self._chain_cols)
        out[:, self.offset_joints] += x[k:k + len(self.offset_joints)]
        s = self._compliance_start
        if len(self.compliance_joints):
            out[:, self.compliance_joints] += self.gravity_torques(th) * x[s:self.n_dense]
        for (cols, w), j, s in zip(interps, self.map_joints, self.map_starts):
            out[:, j] += np.sum(w * x[s + cols], axis=1)
        return out

    def positions(self, commands, dirs=None, x=None) -> np.ndarray:
        """Tool point (M, 3) mm in the root frame for commands (M, N) deg and dirs (M, N) ±1."""
        th, dirs = self._commands(commands, dirs)
        x = self._x(x)
        return self.chain.positions(self._actual(th, self._interpolations(th, dirs), x),
                                    self.chain_parameters(x))

    def jacobian(self, commands, dirs=None, x=None):
        """Tool point (M, 3) mm and its :class:`PositionJacobian` over ``names``.

        Geometric and tool columns are the chain's analytic ones, offsets the
        joint-angle column ∂p/∂θ_i (mm/deg); map node c of reading k is
        ∂p/∂θ_i times its Eq. (7) weight (sparse, ≤ 2 nodes per joint)."""
        th, dirs = self._commands(commands, dirs)
        x = self._x(x)
        interps = self._interpolations(th, dirs)
        n = self.chain.n_joints
        p, jac = self.chain.jacobian(self._actual(th, interps, x), self.chain_parameters(x))
        dense = np.concatenate([jac[:, :, n + self._chain_cols], jac[:, :, self.offset_joints],
                                jac[:, :, self.compliance_joints] * self.gravity_torques(th)[:, None, :]], axis=2)
        maps = tuple((s, j, cols, w) for s, j, (cols, w) in zip(self.map_starts, self.map_joints, interps))
        return p, PositionJacobian(dense, jac[:, :, :n], maps, self.n_params)

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values or uncertainties) in result.json's keys (formats.md,
        serial robots): the location errors and ``dh`` offsets by name, ``tool_offset_mm`` [x, y,
        z], ``error_map`` keyed by joint name (``grid_deg``, ``forward_deg``, and ``reverse_deg``
        when bidirectional). A held tool coordinate (planar robot) is its held value, or 0 when
        ``uncertainty``."""
        v = self._check(v)
        out = {name: float(v[i]) for i, name in enumerate(self.names[:self.n_dense])
               if name not in TOOL_NAMES}
        n = self.chain.n_joints
        tool = np.zeros(3) if uncertainty else self.chain_params[6 * n:].copy()
        k = len(self._chain_cols) - len(self._tool_cols)
        tool[np.array(self._tool_cols, dtype=int) - 6 * n] = v[k:len(self._chain_cols)]
        out["tool_offset_mm"] = tool.tolist()
        if self.maps:
            out["error_map"] = {m.joint: m.with_values(v[s:s + m.n_values]).to_dict()
                                for s, m in zip(self.map_starts, self.maps)}
        return out

    def roughness(self) -> Optional[sp.csr_matrix]:
        """Roughness rows R over x (every map's :meth:`JointMap.roughness` at its columns): the smoothness prior
        ½ λ ‖R x‖² of issue 23; None without maps."""
        blocks = [(s, m.roughness()) for s, m in zip(self.map_starts, self.maps)]
        blocks = [(s, R) for s, R in blocks if R.shape[0]]
        if not blocks:
            return None
        rows = [sp.hstack([sp.csr_matrix((R.shape[0], s)), R,
                           sp.csr_matrix((R.shape[0], self.n_params - s - R.shape[1]))]) for s, R in blocks]
        return sp.vstack(rows, format="csr")

    def support(self, commands, dirs=None) -> list:
        """Per map: its readings' interpolation weight on every entry of ``values`` (000 Eq. (7)-(9)), summed over
        the distinct poses of ``commands`` (M, N) deg: how many poses' worth of readings reach each node in each
        direction."""
        th, dirs = self._commands(commands, dirs)
        key = th if dirs is None else np.hstack([th, dirs])
        first = np.unique(key, axis=0, return_index=True)[1]
        th, dirs = th[first], None if dirs is None else dirs[first]
        out = []
        for (cols, w), m in zip(self._interpolations(th, dirs), self.maps):
            sup = np.zeros(m.n_values)
            np.add.at(sup, cols.ravel(), w.ravel())
            out.append(sup)
        return out

    #: The end nodes of a map branch that together are reached by less than this many poses' worth of interpolation
    #: weight are no parameters (:meth:`ties`): at the ends of a joint's range a random-pose campaign approaches
    #: each node from one side only, and one reading at weight 0.01 would otherwise set a node to its noise x 100
    #: (or the smoothness prior extrapolate a slope far beyond the readings). Thin nodes between read ones stay
    #: parameters: the smoothness prior holds them between their neighbours.
    MIN_NODE_SUPPORT = 1.0

    def ties(self, commands, dirs=None) -> Tuple[np.ndarray, list, list]:
        """(A, tied, targets): linear equalities A x = 0 that make the end nodes of every map branch that the readings
        of ``commands`` barely reach (together less than :attr:`MIN_NODE_SUPPORT` poses' weight counted from the
        grid's end) follow read ones (issue 23, "maps span the data"):
        a node read in the other direction only keeps the backlash of the nearest node read both ways
        (f_i − r_i = f_e − r_e), or, when none is, the value of the nearest node read in its own direction; a
        node read in neither holds the nearest read value of its direction (as ``--outside clamp`` would).
        ``tied``: the tied parameters' names; ``targets``: what each follows (text)."""
        rows, tied, targets = [], [], []
        for start, m, sup in zip(self.map_starts, self.maps, self.support(commands, dirs)):
            n = m.emap.n_nodes
            g = m.emap.grid_deg
            branches = 2 if m.bidirectional else 1
            ok = [_read_span(sup[b * n:(b + 1) * n], self.MIN_NODE_SUPPORT) for b in range(branches)]
            both = ok[0] & ok[1] if branches == 2 else ok[0]

            def nearest(mask, i):
                idx = np.flatnonzero(mask)
                return int(idx[np.argmin(np.abs(g[idx] - g[i]))]) if idx.size else None

            for b in range(branches):
                other = 1 - b
                for i in np.flatnonzero(~ok[b]):
                    row = np.zeros(self.n_params)
                    me = start + b * n + i
                    row[me] = 1.0
                    e = nearest(both, i) if branches == 2 and ok[other][i] else None
                    if e is not None:  # f_i - r_i = f_e - r_e (the backlash of the nearest node read both ways)
                        row[start + other * n + i] -= 1.0
                        row[start + b * n + e] -= 1.0
                        row[start + other * n + e] += 1.0
                        text = f"the {('reverse', 'forward')[b]} branch there at the backlash of {g[e]:g} deg"
                    else:
                        e = nearest(ok[b], i)
                        if e is None:
                            continue  # (a branch no reading reaches at all: the identifiability check names it)
                        row[start + b * n + e] -= 1.0
                        text = f"its value at {g[e]:g} deg"
                    rows.append(row)
                    tied.append(self.names[me])
                    targets.append(text)
        A = np.vstack(rows) if rows else np.zeros((0, self.n_params))
        return A, tied, targets

    def level_rows(self) -> Dict[str, Tuple[np.ndarray, str]]:
        """Per joint with an offset or a map: (row on x, text) of its angle level —
        the offset itself (dh) or the map level of :meth:`JointMap.level_row`."""
        out = {}
        joints = self.chain.joint_names
        k = len(self._chain_cols)
        for i, j in enumerate(self.offset_joints):
            row = np.zeros(self.n_params)
            row[k + i] = 1.0
            out[joints[j]] = (row, f"{joints[j]}_offset_deg")
        for s, m in zip(self.map_starts, self.maps):
            local, at = m.level_row()
            row = np.zeros(self.n_params)
            row[s:s + m.n_values] = local
            text = (f"({m.joint} map at {at:g} deg, mean of +1 and -1)" if m.bidirectional
                    else f"({m.joint} map at {at:g} deg)")
            out[m.joint] = (row, text)
        return out

    #: Plausibility bounds of a solution (:meth:`implausible`): a joint frame's location error beyond
    #: ``LOCATION_BOUND_MM`` / ``LOCATION_BOUND_DEG`` is not an error of a robot built to its model file (machining
    #: and assembly give tenths of a mm and hundredths of a degree; 50 mm / 10 deg is a wrong model or a unit slip:
    #: readings in metres "correct" links by hundreds of mm); a joint offset or map value beyond
    #: ``MAX_DEVIATION_DEG`` (the SCARA's :attr:`~olti_drake.model.scara.ScaraPositionModel.MAX_DEVIATION_DEG`)
    #: is no positioning deviation (a joint column in radians gives hundreds of degrees); a tool point more than
    #: ``TOOL_BOUND_MM`` from its given nominal is another tool (a mount's drawing is good to a mm), and one
    #: without a nominal (0, 0, 0) farther than the robot's reach is none.
    LOCATION_BOUND_MM = 50.0
    LOCATION_BOUND_DEG = 10.0
    MAX_DEVIATION_DEG = 10.0
    TOOL_BOUND_MM = 100.0

    def implausible(self, x, reach_mm: Optional[float] = None) -> list:
        """Physically impossible values of x, one phrase each naming the parameter (empty: plausible):
        location errors beyond :attr:`LOCATION_BOUND_MM` / :attr:`LOCATION_BOUND_DEG`, joint offsets and map
        values beyond :attr:`MAX_DEVIATION_DEG`, a tool point more than :attr:`TOOL_BOUND_MM` from its nominal
        (the start; without one, beyond ``reach_mm`` when given)."""
        x = self._check(x)
        out = []
        hint = "(readings in mm and joint angles in degrees? the right robot model file?)"
        names = self.geometric_names
        bounds = np.array([self.LOCATION_BOUND_DEG if g.endswith("_deg") else self.LOCATION_BOUND_MM for g in names])
        excess = np.abs(x[:len(names)]) / bounds if len(names) else np.zeros(0)
        beyond = np.flatnonzero(~(excess <= 1))
        if beyond.size:
            i = int(beyond[np.argmax(np.where(np.isfinite(excess[beyond]), excess[beyond], np.inf))])
            unit = "deg" if names[i].endswith("_deg") else "mm"
            more = f" (and {beyond.size - 1} more)" if beyond.size > 1 else ""
            out.append(f"{names[i]} = {x[i]:.6g} {unit}{more} is beyond {bounds[i]:g} {unit}, no location error "
                       f"of a joint frame {hint}")
            hint = "(readings in mm?)"
        n = self.chain.n_joints
        nominal = self.chain_params[6 * n:]
        tool = self.chain_parameters(x)[6 * n:]
        off = float(np.linalg.norm(tool - nominal))
        if np.any(nominal != 0) and not off <= self.TOOL_BOUND_MM:
            out.append(f"tool_offset_mm = ({tool[0]:.6g}, {tool[1]:.6g}, {tool[2]:.6g}) is {off:.6g} mm from its "
                       f"nominal ({nominal[0]:g}, {nominal[1]:g}, {nominal[2]:g}), over {self.TOOL_BOUND_MM:g} mm "
                       f"{hint}")
        elif reach_mm is not None and not np.any(nominal != 0) and not off <= reach_mm:
            out.append(f"tool_offset_mm = ({tool[0]:.6g}, {tool[1]:.6g}, {tool[2]:.6g}) is {off:.6g} mm from the "
                       f"tool frame, beyond the robot's reach {reach_mm:.6g} mm {hint}")
        k = len(self._chain_cols)
        angles = [(i, self.names[i]) for i in range(k, self._compliance_start)]
        angles += [(i, self.names[i]) for i in range(self.n_dense, self.n_params)]
        if angles:
            idx = np.array([i for i, _ in angles])
            dev = np.abs(x[idx])
            if not dev.max() <= self.MAX_DEVIATION_DEG:
                i = int(idx[np.argmax(np.where(np.isfinite(dev), dev, np.inf))])
                # A deviation near a multiple of 180 deg is the joint turned over (a fit that found the mirror pose
                # of the arm from a far start), not a unit slip: say so.
                turns = abs(x[i]) / 180.0
                why = (f"the joint turned by {180 * round(turns):g} deg from its zero -- a flipped solution: check "
                       f"the joint's zero in the model file and the start" if abs(turns - round(turns)) * 180 <=
                       self.MAX_DEVIATION_DEG and round(turns) >= 1 else "a joint column in radians?")
                out.append(f"{self.names[i]} = {x[i]:.6g} deg is beyond {self.MAX_DEVIATION_DEG:g} deg, no "
                           f"positioning deviation ({why})")
        return out


def _read_span(support, least: float) -> np.ndarray:
    """Nodes of a branch from the first to the last whose cumulative support, counted from that end of the grid,
    reaches ``least`` (True inside): the branch's nodes beyond are the barely read ends."""
    lo = np.cumsum(support) >= least
    hi = np.cumsum(support[::-1])[::-1] >= least
    return lo & hi


def build_position_model(chain: SerialChain, commands, dirs=None, *, kind: str = "errormap",
                         grid_step_deg: float = 15.0, grids: Optional[Dict[str, Sequence[float]]] = None,
                         tool_offset_mm=(0.0, 0.0, 0.0), chain_params=None,
                         n_poses: int = 60, seed: int = 0, compliance: bool = False,
                         planar: Optional[int] = None) -> SerialPositionModel:
    """The model of ``kind`` for a campaign's commands (M, N) deg.

    Free geometric parameters: the base set of :func:`base_parameter_set`
    (root frame, offsets as the maps' constant parts) at ``chain_params``
    (default: zero location errors and ``tool_offset_mm``). ``dh`` keeps the
    base set's joint offsets; ``errormap`` puts a map on every joint whose
    angle any reading depends on, nodes ``grids[joint]`` or every
    ``grid_step_deg`` over the joint's commanded range (:func:`grid_every`),
    bidirectional when ``dirs`` is given. ``compliance``: a joint compliance
    c_i under gravity for every joint whose gravity torque varies over the
    campaign by at least :data:`MIN_TORQUE_SPAN_NM` (``--compliance``).
    ``model.dropped`` names what was left out and why (the base set's reasons).
    ``planar``: the root axis normal to a planar robot's plane (readings in the plane): the base
    set's planar reduction, the tool offset along the axis held (``held_tool``).
    """
    if kind not in MODEL_KINDS:
        raise ValueError(f"model: 'dh' or 'errormap', not {kind!r}")
    th = np.atleast_2d(np.asarray(commands, float))
    if th.shape[1] != chain.n_joints or th.shape[0] == 0:
        raise ValueError(f"commands: need (M, {chain.n_joints}) joint angles, got shape {th.shape}")
    params = chain.nominal_parameters(tool_offset_mm) if chain_params is None else np.asarray(chain_params, float)
    base = base_parameter_set(chain, params, n_poses=n_poses, seed=seed, planar=planar)
    held_tool = [t for t in TOOL_NAMES if t not in base.kept]
    offset_names = {f"{j}_offset_deg": j for j in chain.joint_names}
    geometric = [k for k in base.kept if k in chain.parameter_names()[:6 * chain.n_joints]]
    kept_offsets = [offset_names[k] for k in base.kept if k in offset_names]
    dropped = [(k, why) for k, why in base.dropped if k not in offset_names]  # (held tool coordinates too)
    compliant = _compliant_joints(chain, th, dropped) if compliance else []
    if kind == "dh":
        dropped += [(k, why) for k, why in base.dropped if k in offset_names]
        return SerialPositionModel(chain, kind, geometric, params, offsets=kept_offsets, dropped=dropped,
                                   compliance=compliant, held_tool=held_tool)
    grids = dict(grids or {})
    bad = [g for g in grids if g not in chain.joint_names]
    if bad:
        raise ValueError(f"grid for '{bad[0]}': no such joint on the chain ({', '.join(chain.joint_names)})")
    unseen = {offset_names[k] for k, why in base.dropped if k in offset_names and why.startswith("no reading")}
    maps = []
    for i, joint in enumerate(chain.joint_names):
        if joint in unseen:
            dropped.append((f"{joint} error map", "no reading depends on it (the tool point is on its axis)"))
            continue
        grid = grids.get(joint)
        if grid is None:
            grid = grid_every(grid_step_deg, th[:, i].min(), th[:, i].max())
        maps.append(JointMap.zeros(joint, grid, bidirectional=dirs is not None))
    return SerialPositionModel(chain, kind, geometric, params, maps=maps, dropped=dropped, compliance=compliant,
                               held_tool=held_tool)


#: A joint whose gravity torque spans less than this over the campaign (N·m), or less than
#: :data:`MIN_TORQUE_SHARE` of the largest span of the chain, gets no compliance parameter: its deflection
#: would be a constant the offset or map level already holds, or too small to tell from the map's shape
#: (wrist joints carry little mass).
MIN_TORQUE_SPAN_NM = 0.5
MIN_TORQUE_SHARE = 0.1


def _compliant_joints(chain: SerialChain, th, dropped: list) -> list:
    """Joints whose gravity torque varies over the commands ``th``; the others appended to ``dropped``."""
    from olti_drake.model.chain import gravity_torques

    span = np.ptp(gravity_torques(chain, th), axis=0)
    need = max(MIN_TORQUE_SPAN_NM, MIN_TORQUE_SHARE * float(span.max()))
    out = []
    for joint, s in zip(chain.joint_names, span):
        if s >= need:
            out.append(joint)
        else:
            dropped.append((f"{joint}_compliance_deg_per_Nm",
                            f"its gravity torque spans {s:.2g} N·m over the campaign, below {need:.2g} N·m "
                            f"(max({MIN_TORQUE_SPAN_NM:g}, {MIN_TORQUE_SHARE:g} x the largest joint's)): a vertical "
                            f"axis, a light link, or no inertial data in the model file"))
    return out


# --------------------------------------------------------------- measurements
class _Measurement:
    """Readings of the tool point: ``names`` = the model's, then the measurement's own."""

    kind = ""

    def __init__(self, model: SerialPositionModel, commands, dirs):
        self.model = model
        self.commands, self.dirs = model._commands(commands, dirs)
        self.own_names: Tuple[str, ...] = ()
        # A pose read from several stations is evaluated once (the FK is most of the time).
        key = self.commands if self.dirs is None else np.hstack([self.commands, self.dirs])
        unique, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        self._poses = None if len(unique) == len(key) else (first, inverse.ravel())

    @property
    def names(self) -> Tuple[str, ...]:
        return self.model.names + self.own_names

    def start_vector(self) -> np.ndarray:
        return np.concatenate([self.model.start_vector(), self._own_start])

    def _split(self, x):
        x = np.asarray(x, float)
        if x.shape != (len(self.names),):
            raise ValueError(f"parameter vector: {x.size} values, the problem has {len(self.names)}")
        return x[:self.model.n_params], x[self.model.n_params:]

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector in result.json's keys: the model's, then the measurement's
        (``uncertainty``: held coordinates are 0, not their held values)."""
        vm, own = self._split(v)
        return {**self.model.layout(vm, uncertainty), **self._own_layout(own, uncertainty)}

    def ties(self):
        """The model's :meth:`SerialPositionModel.ties` for this measurement's poses, over all of ``names``:
        (A, tied names, what each follows)."""
        A, tied, targets = self.model.ties(self.commands, self.dirs)
        return np.hstack([A, np.zeros((A.shape[0], len(self.own_names)))]), tied, targets

    def roughness(self):
        """The model's roughness rows (:meth:`SerialPositionModel.roughness`) over all of ``names`` (the
        measurement's own parameters have none); None without maps."""
        R = self.model.roughness()
        if R is None:
            return None
        return sp.hstack([R, sp.csr_matrix((R.shape[0], len(self.own_names)))], format="csr")

    def _position_jacobian(self, x_model):
        """Tool points (M, 3) and their :class:`PositionJacobian`, each distinct pose evaluated once."""
        if self._poses is None:
            return self.model.jacobian(self.commands, self.dirs, x_model)
        first, inverse = self._poses
        p, jac = self.model.jacobian(self.commands[first], None if self.dirs is None else self.dirs[first],
                                     x_model)
        return p[inverse], jac.take(inverse)

    #: A station (a tracker) farther from the robot's root than this many reaches is absurd (:meth:`implausible`):
    #: a robot is measured from metres, not from tens of its reaches.
    STATION_REACHES = 20.0

    def reach_mm(self) -> float:
        """The farthest the start model puts the tool point from the root over the campaign's poses, mm."""
        if getattr(self, "_reach", None) is None:
            p = self.model.positions(self.commands, self.dirs)
            self._reach = max(float(np.linalg.norm(p, axis=1).max()), 1e-9)
        return self._reach

    def reading_spans(self):
        """(the spread of the readings, the spread of the tool points the start model predicts), mm: readings
        spread far less than the robot moves are in another unit (the engine's check of a residual far below
        the reading uncertainty, :meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.residual_warnings`)."""
        p = self.model.positions(self.commands, self.dirs)
        return self._reading_spread(), float(np.ptp(p, axis=0).max())

    def _far(self, where, what) -> list:
        """One phrase when a point ``where`` (3,) mm lies beyond :attr:`STATION_REACHES` reaches of the root."""
        far, bound = float(np.linalg.norm(where)), self.STATION_REACHES * self.reach_mm()
        return [] if far <= bound else [f"{what} lies {far:.6g} mm from the robot's root, over "
                                        f"{self.STATION_REACHES:g} x its reach {self.reach_mm():.6g} mm"]


class DistanceMeasurement(_Measurement):
    """Distance readings from stations (000 Eq. (10) in 3D, 001 Eq. (3)), mm.

    r_k = ‖p_k − P_j‖ − d0_j − d_k for reading k taken from station j, written once in
    :func:`olti_drake.model.measurements.distance_residual` (shared with ``distance_rows_nd``); what is
    this measurement's own is the stations' columns (planar stations), the drift and the directions. Own
    parameters: ``P<j>_x_mm, P<j>_y_mm, P<j>_z_mm`` per station, then
    ``d0_<j>_mm`` per station (j = the station labels of the file, ascending).

    With ``time_h`` (the time of every reading, hours) the dead path drifts
    linearly during the campaign (air, thermal growth of the beam path):
    d0_j(t) = d0_j + v_j·(t − t̄_j), own parameters ``drift_<j>_mm_per_h`` after
    the dead paths; t̄_j (``drift_reference_h``) is the mean time of station j's
    readings, so d0_j stays the dead path at mid-campaign.

    ``plane`` (a root axis 0-2, a unit normal (3,), or None; :func:`~olti_drake.model.chain.robot_plane`):
    a planar robot's readings in its plane cannot see the stations' distance from the plane (the beam
    stays in it): each station stays in the plane through its position in ``stations_mm``, and the own
    parameters are its two root coordinates other than ``held_axis`` (the axis the normal is largest
    along). For a root axis the held coordinate is the plane's height; for a tilted plane it follows from
    the other two (P_h = (level − n_f·P_f) / n_h), and its uncertainty is stated 0 like a held one.
    """

    kind = "distance"

    def __init__(self, model, commands, dirs, station, displacement_mm,
                 stations_mm=None, dead_paths_mm=None, time_h=None, drift_mm_per_h=None, drift_reference_h=None,
                 plane=None):
        super().__init__(model, commands, dirs)
        station = np.asarray(station).ravel()
        self.labels = np.unique(station)
        self.station = np.searchsorted(self.labels, station)
        self.displacement = np.asarray(displacement_mm, float).ravel()
        if not (len(station) == len(self.displacement) == len(self.commands)):
            raise ValueError("distance campaign: station, displacement and commands differ in length")
        nt = len(self.labels)
        self.plane = plane
        self._normal, _, self.held_axis = plane_frame(plane) if plane is not None else (None, None, None)
        self._free = [c for c in range(3) if c != self.held_axis]
        self.own_names = tuple(f"P{j}_{'xyz'[c]}_mm" for j in self.labels for c in self._free) + tuple(
            f"d0_{j}_mm" for j in self.labels)
        P = np.zeros((nt, 3)) if stations_mm is None else np.asarray(stations_mm, float).reshape(nt, 3)
        self._level = None if plane is None else P @ self._normal  # each station's plane (planar robot)
        d0 = np.zeros(nt) if dead_paths_mm is None else np.asarray(dead_paths_mm, float).reshape(nt)
        self._own_start = np.concatenate([P[:, self._free].ravel(), d0])
        self.time_h = self.drift_reference_h = None
        if time_h is not None:
            self.time_h = np.asarray(time_h, float).ravel()
            if self.time_h.shape != self.displacement.shape or not np.all(np.isfinite(self.time_h)):
                raise ValueError("distance campaign: times must be finite, one per reading")
            self.drift_reference_h = (np.array([self.time_h[self.station == j].mean() for j in range(nt)])
                                      if drift_reference_h is None else np.asarray(drift_reference_h, float))
            v = np.zeros(nt) if drift_mm_per_h is None else np.asarray(drift_mm_per_h, float).reshape(nt)
            self.own_names += tuple(f"drift_{j}_mm_per_h" for j in self.labels)
            self._own_start = np.concatenate([self._own_start, v])

    def _stations(self, own, held_values: bool = True) -> np.ndarray:
        """(Nt, 3) stations from the own parameters: the free coordinates, the held one in the station's plane
        (or 0: ``held_values=False``, an uncertainty)."""
        nt, nf = len(self.labels), len(self._free)
        P = np.zeros((nt, 3))
        P[:, self._free] = own[:nf * nt].reshape(nt, nf)
        if held_values and self.held_axis is not None:  # (a root axis: the held height itself, bit for bit)
            n, h = self._normal, self.held_axis
            P[:, h] = (self._level - P[:, self._free] @ n[self._free]) / n[h]
        return P

    def _parts(self, x):
        """Model part, stations (Nt, 3), and the dead path of every reading (drift included)."""
        xm, own = self._split(x)
        nt, nf = len(self.labels), len(self._free)
        d0 = own[nf * nt:(nf + 1) * nt][self.station]
        if self.time_h is not None:
            d0 = d0 + own[(nf + 1) * nt:][self.station] * self._dt()
        return xm, self._stations(own), d0

    def _dt(self) -> np.ndarray:
        return self.time_h - self.drift_reference_h[self.station]

    def _own_layout(self, own, uncertainty=False) -> dict:
        nt, nf = len(self.labels), len(self._free)
        out = {"stations_mm": self._stations(own, not uncertainty).tolist(),
               "dead_paths_mm": own[nf * nt:(nf + 1) * nt].tolist()}
        if self.time_h is not None:  # (the result adds drift_reference_h: a constant, not a parameter)
            out["drift_mm_per_h"] = own[(nf + 1) * nt:].tolist()
        return out

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """‖p − P_j‖ of every reading at x, mm (from the ``residuals`` at x when given: r + d0 + reading)."""
        xm, P, d0 = self._parts(x)
        if residuals is not None:
            return residuals + d0 + self.displacement
        return lengths(self.model.positions(self.commands, self.dirs, xm) - P[self.station])

    def predict(self, x) -> np.ndarray:
        """Expected readings ‖p − P_j‖ − d0_j (mm): the residual of a zero reading (000 Eq. 10, 001 Eq. 3)."""
        xm, P, d0 = self._parts(x)
        p = self.model.positions(self.commands, self.dirs, xm)
        return distance_residual(p, P[self.station], d0, 0.0)[0]

    def residuals(self, x):
        """r (M,) = ‖p − P_j‖ − d0_j − d mm (000 Eq. 10, 001 Eq. 3: the shared
        :func:`~olti_drake.model.measurements.distance_residual`) and the sparse dr/dx (M, P + 4 Nt): u·∂p/∂x,
        −u for P_j (its free coordinates), −1 for d0_j, −(t − t̄_j) for the drift (mm/mm, mm/deg, h)."""
        xm, P, d0 = self._parts(x)
        p, jp = self._position_jacobian(xm)
        r, u = distance_residual(p, P[self.station], d0, self.displacement)
        pm, nt, nf = self.model.n_params, len(self.labels), len(self._free)
        cols = [pm + nf * self.station + c for c in range(nf)] + [pm + nf * nt + self.station]
        du = u[:, self._free]
        if self.held_axis is not None:  # (the held coordinate moves with the free ones on a tilted plane)
            n, h = self._normal, self.held_axis
            du = du - u[:, [h]] * (n[self._free] / n[h])
        vals = [-du, -np.ones((len(u), 1))]
        if self.time_h is not None:  # ∂r/∂v_j = −(t − t̄_j)
            cols.append(pm + (nf + 1) * nt + self.station)
            vals.append(-self._dt()[:, None])
        return r, jp.contract(u, np.hstack(vals), np.column_stack(cols), len(self.names))

    def probe(self, model, commands, dirs, rng):
        """The same kind of measurement for ``model`` at other poses, with random stations
        around the reach (for :func:`find_gauge`); readings zero."""
        p = model.positions(commands, dirs)
        reach = max(np.linalg.norm(p[:, self._free], axis=1).max(), 1.0)
        nt = len(self.labels)
        P = rng.normal(size=(nt, 3))
        P[:, [c for c in range(3) if c not in self._free]] = 0.0
        P *= (1.5 * reach / np.linalg.norm(P, axis=1))[:, None]
        if self.held_axis is not None:  # a planar robot's probe: stations in the tool point's plane
            n, h = self._normal, self.held_axis
            P[:, h] = (np.mean(p @ n) - P[:, self._free] @ n[self._free]) / n[h]
        m = len(commands)
        tiled_dirs = None if dirs is None else np.tile(dirs, (nt, 1))
        times = None if self.time_h is None else rng.uniform(0.0, 1.0, nt * m)  # drift: generic, seen
        return DistanceMeasurement(model, np.tile(commands, (nt, 1)), tiled_dirs,
                                   np.repeat(self.labels, m), np.zeros(nt * m), P, np.zeros(nt), time_h=times,
                                   plane=self.plane)

    def _reading_spread(self) -> float:
        return float(np.ptp(self.displacement)) if len(self.displacement) else 0.0

    def implausible(self, x) -> list:
        """The model's implausible values (:meth:`SerialPositionModel.implausible`), then stations beyond
        :attr:`STATION_REACHES` reaches of the root; one phrase each, named."""
        xm, P, _ = self._parts(np.asarray(x, dtype=float))
        out = list(self.model.implausible(xm, self.reach_mm()))
        for j, label in enumerate(self.labels):
            out += self._far(P[j], f"station {label} (P{label}_mm)")
        return out


class PointMeasurement(_Measurement):
    """Tool points measured by a tracker in its own frame (mm): r = R·p + t − m (3 per reading).

    The tracker frame is unknown: own parameters ``frame_x_mm, frame_y_mm,
    frame_z_mm`` (t) and ``frame_rx_deg, frame_ry_deg, frame_rz_deg`` with
    R = Rx·Ry·Rz (the chain's location-error convention; :func:`~olti_drake.model.frames.xyz_rotation`, the
    Jacobian by :func:`~olti_drake.model.frames.turn_rows` as the five-axis tracker's). Residual rows are
    x, y, z of reading 0, then reading 1, ...
    """

    kind = "point"

    def __init__(self, model, commands, dirs, points_mm, frame=None):
        super().__init__(model, commands, dirs)
        self.points = np.asarray(points_mm, float).reshape(-1, 3)
        if len(self.points) != len(self.commands):
            raise ValueError("point campaign: points and commands differ in length")
        self.own_names = FRAME_NAMES
        self._own_start = np.zeros(6) if frame is None else np.asarray(frame, float).reshape(6)

    def _parts(self, x):
        xm, own = self._split(x)
        return xm, own

    def _own_layout(self, own, uncertainty=False) -> dict:
        return {"tracker_frame": {"translation_mm": own[:3].tolist(), "rotation_deg": own[3:].tolist(),
                                  "convention": XYZ_CONVENTION}}

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """Distance from the tracker (its frame's origin) to every tool point at x, mm (``residuals``: unused,
        a point's residual does not give it)."""
        return np.linalg.norm(self.predict(x), axis=1)

    def predict(self, x) -> np.ndarray:
        """Tool points in the tracker frame (M, 3) mm."""
        xm, frame = self._parts(x)
        return into_frame(self.model.positions(self.commands, self.dirs, xm), frame)

    def residuals(self, x):
        """r (3M,) mm and the sparse dr/dx (3M, P + 6): R·∂p/∂x, I for t, u_k × (R p) for the angles."""
        xm, frame = self._parts(x)
        rot, axes = xyz_rotation(frame[3:])
        p, jp = self._position_jacobian(xm)
        q = p @ rot.T
        r = (q + frame[:3] - self.points).ravel()
        m, pm = len(p), self.model.n_params
        spin = turn_rows(q, axes, DEG)  # (M, 3, 3), the frame's angles as the five-axis tracker's
        vals = np.concatenate([np.ones((m, 3, 1)), spin], axis=2).reshape(3 * m, 4)
        cols = np.column_stack([pm + np.tile(np.arange(3), m)] + [np.full(3 * m, pm + 3 + k) for k in range(3)])
        return r, jp.rotated(rot).tocsr(vals, cols, len(self.names))

    def probe(self, model, commands, dirs, rng):
        frame = np.concatenate([rng.normal(0, 500.0, 3), rng.uniform(-30, 30, 3)])
        return PointMeasurement(model, commands, dirs, np.zeros((len(commands), 3)), frame)

    def _reading_spread(self) -> float:
        return float(np.ptp(self.points, axis=0).max()) if len(self.points) else 0.0

    def implausible(self, x) -> list:
        """The model's implausible values (:meth:`SerialPositionModel.implausible`), then a tracker frame whose
        origin lies beyond :attr:`STATION_REACHES` reaches of the root; one phrase each, named."""
        xm, frame = self._parts(np.asarray(x, dtype=float))
        return list(self.model.implausible(xm, self.reach_mm())) + self._far(frame[:3], "the tracker (frame_*_mm)")


class RootPositionMeasurement(_Measurement):
    """Tool points measured in the robot's root frame (mm): r = p − m (3 per reading), no own
    parameters. What the model alone can and cannot see."""

    kind = "root"

    def __init__(self, model, commands, dirs, points_mm):
        super().__init__(model, commands, dirs)
        self.points = np.asarray(points_mm, float).reshape(-1, 3)
        self._own_start = np.zeros(0)

    def _own_layout(self, own, uncertainty=False) -> dict:
        return {}

    def predict(self, x) -> np.ndarray:
        return self.model.positions(self.commands, self.dirs, self._split(x)[0])

    def residuals(self, x):
        p, jp = self._position_jacobian(self._split(x)[0])
        return (p - self.points).ravel(), jp.tocsr()

    def probe(self, model, commands, dirs, rng):
        return RootPositionMeasurement(model, commands, dirs, np.zeros((len(commands), 3)))


def tracker_to_base(points_mm, frame) -> np.ndarray:
    """Points measured in a tracker's frame (M, 3) mm into the robot's base frame, by a tracker frame of
    :class:`PointMeasurement` (6: translation t mm, rotation angles deg, m = R·p + t): p = Rᵀ (m − t)."""
    return out_of_frame(points_mm, frame)


# --------------------------------------------------------------------- gauge
@dataclass(frozen=True)
class GaugeConstraint:
    """One linear constraint ``row · x = value`` on a problem's parameters, and what it fixes."""

    name: str
    row: np.ndarray
    value: float
    text: str


@dataclass(frozen=True)
class Gauge:
    """What the readings cannot see, fixed by ``constraints`` (A x = b).

    ``null_dimension`` is the dimension of the Jacobian's null space at random
    poses (random stations / tracker frame) without the constraints; the
    constraints make it zero. ``sentence`` is for result.json's ``gauge``.
    """

    constraints: Tuple[GaugeConstraint, ...]
    null_dimension: int
    sentence: str
    n_params: int

    @property
    def A(self) -> np.ndarray:
        return np.array([c.row for c in self.constraints]).reshape(len(self.constraints), self.n_params)

    @property
    def b(self) -> np.ndarray:
        return np.array([c.value for c in self.constraints])

    @property
    def names(self) -> Tuple[str, ...]:
        return tuple(c.name for c in self.constraints)


def find_gauge(problem, x=None, *, n_poses: int = 40, seed: int = 0) -> Gauge:
    """The gauge of a measurement problem, worked out numerically.

    The model is reduced to its levels (a constant angle offset for each joint
    with an offset or a map: the non-constant part of a map cannot trade with
    a rigid motion), the same measurement is taken at ``n_poses`` seeded random
    poses within the commanded ranges from random stations (or a random tracker
    frame), and the null space of its Jacobian (unit-scaled columns,
    singular values < ``NULL_RTOL``) is fixed by constraints chosen greedily in
    priority order: each joint's free location errors then its level (chain
    order), the tool offset, the measurement's own parameters. A location error
    is held at its value in ``x`` (default the start vector); a level at 0.
    For distances (and tracker points) the null space is the rigid motion of
    the robot together with the stations (the tracker frame): 6 freedoms; plus,
    for every joint whose zero the tool point cannot see (its level trades with
    other parameters), one. Raises ValueError naming the parameters if the
    candidates cannot fix it.
    """
    model = problem.model
    x = problem.start_vector() if x is None else np.asarray(x, float)
    reduced = _level_model(model, x[:model.n_params])
    rng = np.random.default_rng(seed)
    rng_cmd = model.command_ranges()
    commands = rng.uniform(rng_cmd[:, 0], rng_cmd[:, 1], size=(n_poses, model.chain.n_joints))
    dirs = rng.choice([-1.0, 1.0], size=commands.shape) if model.bidirectional else None
    probe = problem.probe(reduced, commands, dirs, rng)
    _, jac = probe.residuals(probe.start_vector())
    jac = jac.toarray()
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    _, s, vt = np.linalg.svd(jac / scale, full_matrices=False)
    null = vt[s < NULL_RTOL * s[0]].T / scale[:, None]  # unscaled null directions (P_red, k)
    k = null.shape[1]
    # rank tests on the orthonormal (unit-scaled) basis: a row's size is how much that
    # parameter takes part in the unseen directions, whatever its unit
    chosen = _greedy_rows(null * scale[:, None], _candidates(reduced, probe))
    if len(chosen) < k:
        big = np.argsort(-np.abs(null * scale[:, None]).max(axis=1))[:4]
        raise ValueError("readings cannot see a combination of " + ", ".join(probe.names[i] for i in big)
                         + " and no gauge constraint fixes it")
    return _gauge_from(problem, probe, null, chosen, x)


def _level_model(model: SerialPositionModel, x_model) -> SerialPositionModel:
    """``dh`` with a constant offset on each joint that has an offset or a map, same free
    location errors and tool, at the location errors and tool of x."""
    joints = model.chain.joint_names
    levels = sorted(set(model.offset_joints) | set(model.map_joints))
    return SerialPositionModel(model.chain, "dh", model.geometric_names, model.chain_parameters(x_model),
                               offsets=[joints[j] for j in levels], held_tool=model.held_tool)


def _candidates(reduced, probe):
    """Candidate constraints in priority order: index into the reduced problem's names."""
    names = list(probe.names)
    order = []
    for joint in reduced.chain.joint_names:
        order += [i for i, n in enumerate(reduced.geometric_names) if n.startswith(joint + "_")
                  and n[len(joint) + 1:] in GEOMETRIC_SUFFIXES]
        if f"{joint}_offset_deg" in names:
            order.append(names.index(f"{joint}_offset_deg"))
    order += [names.index(t) for t in TOOL_NAMES if t in names]
    order += list(range(reduced.n_params, len(names)))
    return order


def _greedy_rows(null, candidates, tol=1e-2):
    """The candidates, in order, each of which fixes a null direction the earlier ones left -- by at least
    ``tol`` of the null basis's largest entry: a row of tiny weight would hold its direction only through
    that weight (seen at an identified, slightly tilted planar robot: J2_dx_mm held the translation along z)."""
    chosen, fixed = [], np.zeros((0, null.shape[1]))
    if null.size == 0:
        return chosen
    norm = np.abs(null).max()
    for c in candidates:
        if len(chosen) == null.shape[1]:
            break
        trial = np.vstack([fixed, null[c]])
        if np.linalg.matrix_rank(trial, tol * norm) > len(chosen):
            chosen.append(c)
            fixed = trial
    return chosen


def _gauge_from(problem, probe, null, chosen, x) -> Gauge:
    """Lift the chosen reduced-problem rows to ``problem`` and say what each fixes."""
    model = problem.model
    names = list(problem.names)
    levels = model.level_rows()
    moved = null @ np.linalg.inv(null[chosen])  # column i: the direction only constraint i stops
    n_model = probe.model.n_params
    p, pj = probe.model.jacobian(probe.commands, probe.dirs)
    jp = pj.tocsr()
    constraints, groups = [], {}
    for i, c in enumerate(chosen):
        pname = probe.names[c]
        row = np.zeros(len(names))
        if pname.endswith("_offset_deg"):
            local, label = levels[pname[:-len("_offset_deg")]]
            row[:model.n_params] = local
            value = 0.0
        else:
            row[names.index(pname)] = 1.0
            value, label = float(x[names.index(pname)]), pname
        what, detail = _what(problem, probe, moved[:, i], c, n_model, p, jp)
        text = f"{label} = {value:g} fixes " + (f"the {detail} of {what}" if detail else what)
        constraints.append(GaugeConstraint(f"gauge: {label}", row, value, text))
        groups.setdefault(what, []).append(f"{label} = {value:g}" + (f" ({detail})" if detail else ""))
    sentence = "; ".join(f"{what}: fixed by {', '.join(fixes)}" for what, fixes in groups.items())
    sentence = sentence[:1].upper() + sentence[1:] + "." if sentence else "none needed: every parameter is seen"
    return Gauge(tuple(constraints), len(chosen), sentence, len(names))


def _what(problem, probe, direction, chosen, n_model, p, jp):
    """(phrase, detail) for the freedom a null direction is: a rigid motion (detail: which
    translation or rotation, in the root frame), or a trade between named parameters."""
    scaled = np.abs(direction) / max(np.abs(direction).max(), 1e-300)
    if problem.kind in ("distance", "point") and np.any(scaled[n_model:] > 1e-6):
        motion = _rigid_motion(p, (jp @ direction[:n_model]).reshape(-1, 3))
        if problem.kind == "distance":
            return "a rigid motion of the robot together with the stations, which distances cannot see", motion
        return "a rigid motion of the robot relative to the unknown tracker frame", motion
    partners = [probe.names[i] for i in np.argsort(-scaled) if i != chosen and scaled[i] > 0.1][:4]
    name = probe.names[chosen]
    subject = f"the zero of {name[:-len('_offset_deg')]}" if name.endswith("_offset_deg") else name
    return f"{subject}, which trades with {', '.join(partners)}", ""


def _rigid_motion(p, dp) -> str:
    """The small rigid motion dp = ω × p + v of the points p (M, 3) mm, in words (root frame)."""
    m = len(p)
    basis = np.zeros((m, 3, 6))
    for k, e in enumerate(np.eye(3)):
        basis[:, :, k] = _cross(np.broadcast_to(e, p.shape), p)
        basis[:, :, 3 + k] = e
    sol = np.linalg.lstsq(basis.reshape(3 * m, 6), dp.ravel(), rcond=None)[0]
    w, v = sol[:3], sol[3:]
    reach = np.abs(p).max()
    # (A translation seen at a slightly tilted pose -- a planar robot's identified result -- carries a rotation
    # of the tilt's order: still a translation.)
    if np.linalg.norm(w) * reach < 1e-2 * np.linalg.norm(v):
        return f"translation along {_direction_words(v)}"
    through = np.cross(w, v) / (w @ w)
    through[np.abs(through) < 1e-6 * reach] = 0.0
    where = ("through the origin" if np.linalg.norm(through) < 1e-6 * reach
             else "through (" + ", ".join(f"{c:.6g}" for c in through) + ") mm")
    return f"rotation about {_direction_words(w)} {where}"


def _direction_words(vec) -> str:
    unit = vec / np.linalg.norm(vec)
    axis = int(np.argmax(np.abs(unit)))
    if abs(abs(unit[axis]) - 1.0) < 1e-9:
        return "xyz"[axis]
    return "(" + ", ".join(f"{c:.4g}" for c in unit) + ")"


# ------------------------------------------------------------ synthetic truth
@dataclass(frozen=True, eq=False)
class SyntheticTruth:
    """A continuous truth for tests (NOT in the model family: harmonics, not piecewise linear).

    ``chain_params`` (6N + 3): joint-frame location errors and the tool offset;
    ``deviations``: a :class:`HarmonicDeviation` per joint (deg via its
    mdeg fields, with backlash); ``stations_mm`` (Nt, 3), ``dead_paths_mm``;
    ``frame`` (6): the tracker frame (mm, deg Rx·Ry·Rz) mapping root to tracker;
    ``compliance_deg_per_Nm`` (N) or None: joint compliance under gravity (+c·τ(θ*)).
    """

    chain: SerialChain
    chain_params: np.ndarray
    deviations: Tuple[HarmonicDeviation, ...]
    stations_mm: np.ndarray
    dead_paths_mm: np.ndarray
    frame: np.ndarray
    compliance_deg_per_Nm: Optional[np.ndarray] = None

    def actual_angles(self, commands, dirs=None) -> np.ndarray:
        th = np.atleast_2d(np.asarray(commands, float))
        d = np.ones_like(th) if dirs is None else np.broadcast_to(np.asarray(dirs, float), th.shape)
        out = th + np.column_stack([dev(th[:, i], d[:, i]) for i, dev in enumerate(self.deviations)])
        if self.compliance_deg_per_Nm is not None:
            from olti_drake.model.chain import gravity_torques

            out = out + gravity_torques(self.chain, th) * np.asarray(self.compliance_deg_per_Nm, float)
        return out

    def positions(self, commands, dirs=None) -> np.ndarray:
        """True tool point (M, 3) mm in the root frame."""
        return self.chain.positions(self.actual_angles(commands, dirs), self.chain_params)


def synthetic_truth(chain: SerialChain, seed: int, *, tool_offset_mm=(40.0, -25.0, 60.0),
                    n_stations: int = 4, location_mm: float = 0.2, location_deg: float = 0.02,
                    deviation_mdeg: float = 20.0, backlash_mdeg: float = 10.0) -> SyntheticTruth:
    """A seeded truth: location errors ~N(0, location_mm / location_deg), a tool offset off the
    last axis, per joint offset + trend + 2 harmonics (amplitudes ~ deviation_mdeg) + backlash
    (~ backlash_mdeg), ``n_stations`` stations spread around the robot at 1.5× its reach on
    the floor side, dead paths 100–500 mm, a tracker frame ~2 m away turned by up to 30°."""
    rng = np.random.default_rng(seed)
    n = chain.n_joints
    geo = np.column_stack([rng.normal(0, location_mm, (n, 3)), rng.normal(0, location_deg, (n, 3))])
    params = np.concatenate([geo.ravel(), np.asarray(tool_offset_mm, float)])
    devs = []
    for _ in range(n):
        harmonics = [Harmonic(rng.uniform(0.3, 1.0) * deviation_mdeg, period, rng.uniform(0, 360))
                     for period in (360.0, rng.choice([45.0, 60.0, 90.0, 120.0]))]
        devs.append(HarmonicDeviation(offset_mdeg=rng.normal(0, deviation_mdeg),
                                      slope_mdeg_per_deg=rng.normal(0, deviation_mdeg / 360),
                                      harmonics=harmonics,
                                      backlash_mdeg=rng.uniform(0.5, 1.0) * backlash_mdeg))
    reach = np.linalg.norm(chain.positions(chain.random_angles(200, seed), params), axis=1).max()
    az = 2 * np.pi * (np.arange(n_stations) / max(n_stations, 1) + rng.uniform(0, 0.1, n_stations))
    stations = np.column_stack([1.5 * reach * np.cos(az), 1.5 * reach * np.sin(az),
                                rng.uniform(-0.6, 0.2, n_stations) * reach])
    frame = np.concatenate([rng.uniform(-2000, 2000, 3), rng.uniform(-30, 30, 3)])
    return SyntheticTruth(chain, params, tuple(devs), stations, rng.uniform(100, 500, n_stations), frame)


@dataclass(frozen=True, eq=False)
class SyntheticCampaign:
    """Readings of a truth: ``commands`` (M, N) deg and ``dirs`` (M, N) ±1 (None if one-directional)
    of the poses; the distance campaign (every pose from every station, station by station):
    ``station`` (M·Nt,), ``displacement_mm``, ``distance_commands``/``distance_dirs``; the point
    campaign ``points_mm`` (M, 3) in the tracker frame."""

    commands: np.ndarray
    dirs: Optional[np.ndarray]
    station: np.ndarray
    distance_commands: np.ndarray
    distance_dirs: Optional[np.ndarray]
    displacement_mm: np.ndarray
    points_mm: np.ndarray


def synthetic_campaign(truth, n_poses: int, seed: int, *, ranges_deg=None, directions="random",
                       noise_mm: float = 0.0) -> SyntheticCampaign:
    """Seeded random poses within ``ranges_deg`` (N, 2) (default the joint limits, ±180° where
    unlimited) and their approach directions: ``"random"`` — each joint of each pose approached
    from a random side (a bidirectional plan's approach move before the pose: every map node sees
    both directions), ``"sequence"`` — the directions of the poses' own sequence (formats.md rule;
    near a range end most approaches come from inside), ``False`` — none (one-directional);
    and the readings of
    ``truth`` (anything with ``positions(commands, dirs)``, ``stations_mm``, ``dead_paths_mm``,
    ``frame``) with Gaussian noise of ``noise_mm`` (standard deviation, mm)."""
    rng = np.random.default_rng(seed)
    chain = truth.chain
    if ranges_deg is None:
        lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -UNLIMITED_RANGE_DEG)
        hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, UNLIMITED_RANGE_DEG)
        ranges_deg = np.column_stack([lo, hi])
    ranges_deg = np.asarray(ranges_deg, float)
    commands = rng.uniform(ranges_deg[:, 0], ranges_deg[:, 1], size=(n_poses, chain.n_joints))
    if directions not in ("random", "sequence", False, None):
        raise ValueError(f"directions: 'random', 'sequence' or False, not {directions!r}")
    dirs = None
    if directions == "random":
        dirs = rng.choice([-1.0, 1.0], size=commands.shape)
    elif directions == "sequence":
        dirs = approach_directions(commands, last_direction=1.0)
    p = truth.positions(commands, dirs)
    nt = len(truth.stations_mm)
    station = np.repeat(np.arange(nt), n_poses)
    dist = np.linalg.norm(np.tile(p, (nt, 1)) - truth.stations_mm[station], axis=1) - truth.dead_paths_mm[station]
    points = into_frame(p, truth.frame)
    return SyntheticCampaign(commands, dirs, station, np.tile(commands, (nt, 1)),
                             None if dirs is None else np.tile(dirs, (nt, 1)),
                             dist + rng.normal(0, noise_mm, dist.shape) if noise_mm else dist,
                             points + rng.normal(0, noise_mm, points.shape) if noise_mm else points)


def tool_point_uncertainty(model, commands, dirs, cov=None, samples=None) -> tuple:
    """(p (M, 3), u (M, 3)) mm: the predicted tool points and their standard uncertainties per coordinate.

    ``cov``: (n, n) covariance of the model's parameters (``model.names``; the linear method), or
    ``samples``: (T, n) Monte Carlo samples of them (their tool points' spread, ddof = 1)."""
    from olti_drake.model.propagation import predicted_std

    p, jac = model.jacobian(commands, dirs)
    if samples is not None:
        pts = np.stack([model.positions(commands, dirs, s) for s in samples])
        return p, pts.std(axis=0, ddof=1)
    return p, predicted_std(jac.tocsr(), cov, dim=3)
