"""Bidirectional angular positioning deviation of a rotary axis (paper 000, Eq. 6-9).

Units: command angles and deviations in **degrees** throughout this module.

Two kinds of deviation share one calling convention, ``dev(theta_deg, direction)
-> deviation_deg`` (vectorized):

* :class:`ErrorMap` -- the identified model: values at an ascending grid of
  command angles, one set per approach direction, linearly interpolated
  (Eq. 7-9 of 000).
* :class:`HarmonicDeviation` -- a *continuous* truth for the simulator (real
  joints are not piecewise linear): offset + trend + harmonics, plus a
  direction-dependent backlash term.

Approach directions (the ±1 of the bidirectional maps, Eq. (7) of 000, §2.2): +1 if the last motion of
the axis before the reading was positive, -1 if negative; an axis that did not
move keeps the direction of its last motion (:func:`approach_directions`).
"""


import dataclasses
from dataclasses import dataclass, field
from typing import List

import numpy as np
import scipy.sparse as sp

#: Command changes smaller than this (deg) count as "did not move".
MOTION_TOLERANCE_DEG = 1e-9
#: Angles this close (deg) outside a grid's ends still count as inside it.
GRID_TOLERANCE_DEG = 1e-9


class OutsideGridError(ValueError):
    """A command angle lies outside an error map's grid and the policy is 'error'.

    ``row`` is the 0-based index of the first offending command.
    """

    def __init__(self, message: str, row: int):
        super().__init__(message)
        self.row = row


def _directions(direction, n: int) -> np.ndarray:
    d = np.broadcast_to(np.asarray(direction, dtype=float), (n,))
    if not np.all(np.isin(d, (-1.0, 1.0))):
        bad = d[~np.isin(d, (-1.0, 1.0))][0]
        raise ValueError(f"approach direction must be +1 or -1, got {bad:g}")
    return d


def approach_directions(commands_deg, last_command_deg=None, last_direction=1.0):
    """Approach direction of every command in a sequence (spec rule of formats.md).

    Args:
        commands_deg: (K,) or (K, n) commanded angles of n axes, in the order
            the axes are moved, deg.
        last_command_deg: the command before the first one (n,), deg; None means
            the first command is where the axis starts (it keeps
            ``last_direction``).
        last_direction: direction of the last motion before the sequence (n,) or
            scalar, +1/-1.

    Returns:
        (K,) or (K, n) array of +1/-1: sign of the last non-zero motion.
    """
    cmd = np.asarray(commands_deg, dtype=float)
    flat = cmd.ndim == 1
    cmd = cmd.reshape(len(cmd), -1)
    start = cmd[:1] if last_command_deg is None else np.reshape(
        np.asarray(last_command_deg, dtype=float), (1, -1))
    step = np.diff(np.vstack([start, cmd]), axis=0)
    sign = np.where(np.abs(step) > MOTION_TOLERANCE_DEG, np.sign(step), 0.0)
    last = np.broadcast_to(np.asarray(last_direction, dtype=float), (cmd.shape[1],))
    # Forward-fill the last non-zero sign (an axis that did not move keeps its
    # direction); rows before any motion take last_direction.
    rows = np.where(sign != 0, np.arange(len(sign))[:, None], -1)
    idx = np.maximum.accumulate(rows, axis=0)
    out = np.where(idx >= 0, np.take_along_axis(sign, np.maximum(idx, 0), axis=0), last)
    return out[:, 0] if flat else out


@dataclass(frozen=True, eq=False)
class ErrorMap:
    """Δθ_map(i, ±1) of one axis on an ascending grid (000 Eq. 6-9), degrees.

    ``forward_deg[i]`` is the deviation at ``grid_deg[i]`` when approached in
    the positive direction (+1), ``reverse_deg[i]`` in the negative one (-1).

    Interpolation (Eq. 7 with α of Eq. 9): between nodes i and i+1,
    Δθ = (1 - α) Δθ(i) + α Δθ(i+1), so at θ* = θ_map(i) the deviation is
    exactly the node-i value. (Eq. 7 as printed puts α on node i, which with α
    from Eq. 9 is backwards.)

    Outside the grid: ``outside="error"`` (default) raises
    :class:`OutsideGridError` naming the axis and the angle -- a map used
    beyond its calibrated range would be a silent wrong answer;
    ``outside="clamp"`` holds the end node's value.
    """

    grid_deg: np.ndarray
    forward_deg: np.ndarray
    reverse_deg: np.ndarray
    axis: str = "J?"
    outside: str = "error"

    def __post_init__(self):
        g = np.asarray(self.grid_deg, dtype=float).ravel()
        f = np.asarray(self.forward_deg, dtype=float).ravel()
        r = np.asarray(self.reverse_deg, dtype=float).ravel()
        name = f"error map {self.axis}"
        if g.size == 0:
            raise ValueError(f"{name}: grid_deg is empty")
        if not (f.size == g.size and r.size == g.size):
            raise ValueError(f"{name}: grid_deg has {g.size} nodes but forward_deg has "
                             f"{f.size} and reverse_deg {r.size}")
        for key, v in (("grid_deg", g), ("forward_deg", f), ("reverse_deg", r)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name}: {key} contains a non-finite value")
        if np.any(np.diff(g) <= 0):
            raise ValueError(f"{name}: grid_deg must be strictly ascending")
        if self.outside not in ("error", "clamp"):
            raise ValueError(f"{name}: outside must be 'error' or 'clamp', got {self.outside!r}")
        object.__setattr__(self, "grid_deg", g)
        object.__setattr__(self, "forward_deg", f)
        object.__setattr__(self, "reverse_deg", r)

    @property
    def n_nodes(self) -> int:
        return self.grid_deg.size

    @property
    def values(self) -> np.ndarray:
        """Node values stacked as [forward..., reverse...] (2N,), deg (Eq. 6 order)."""
        return np.concatenate([self.forward_deg, self.reverse_deg])

    def with_values(self, values) -> "ErrorMap":
        """Same grid and policy, new node values [forward..., reverse...], deg."""
        v = np.asarray(values, dtype=float)
        n = self.n_nodes
        return dataclasses.replace(self, forward_deg=v[:n], reverse_deg=v[n:])

    def interpolation(self, theta_deg, direction):
        """Bracketing nodes and weights of every command (Eq. 8-9 of 000).

        Args:
            theta_deg: (K,) command angles, deg.
            direction: (K,) or scalar approach directions, +1/-1.

        Returns:
            (cols, w), each (K, 2): Δθ_k = Σ_c w[k, c] · values[cols[k, c]],
            with (1-α, α) on the two bracketing nodes, in the forward block
            (0..N-1) for +1 and the reverse block (N..2N-1) for -1. These are
            also dΔθ/d(values): the model is linear in the node values.
        """
        th = np.asarray(theta_deg, dtype=float).ravel()
        d = _directions(direction, th.size)
        g = self.grid_deg
        n = g.size
        if not np.all(np.isfinite(th)):
            raise ValueError(f"error map {self.axis}: command angle is not finite")
        out = (th < g[0] - GRID_TOLERANCE_DEG) | (th > g[-1] + GRID_TOLERANCE_DEG)
        if np.any(out) and self.outside == "error":
            row = int(np.flatnonzero(out)[0])
            raise OutsideGridError(
                f"error map {self.axis}: command angle {th[row]:g} deg is outside the map grid "
                f"[{g[0]:g}, {g[-1]:g}] deg (policy 'error'; clamping would hold the end values)", row)
        thc = np.clip(th, g[0], g[-1])
        block = np.where(d > 0, 0, n)
        if n == 1:  # a constant map: all weight on the single node
            return np.column_stack([block, block]), np.column_stack([np.ones(th.size), np.zeros(th.size)])
        i = np.clip(np.searchsorted(g, thc, side="right") - 1, 0, n - 2)
        alpha = (thc - g[i]) / (g[i + 1] - g[i])  # Eq. (9)
        return np.column_stack([block + i, block + i + 1]), np.column_stack([1.0 - alpha, alpha])

    def roughness(self, bidirectional: bool = True) -> sp.csr_matrix:
        """Roughness rows R on ``values`` [forward..., reverse...] (2N,): ‖R v‖² ≈ ∫ (Δθ'')² dθ* of the forward
        and the reverse branch and of the backlash between them (forward − reverse), deg²/deg³ -- the smoothness
        prior of issue 23 on 000's bidirectional map (Eq. 6-9). Each interior node i gives the divided second
        difference 2[(v_{i+1} − v_i)/h_1 − (v_i − v_{i−1})/h_0]/(h_0 + h_1) (deg/deg²) times √((h_0 + h_1)/2),
        its share of the integral, so grids of any spacing weigh alike. A linear map has no roughness; a map of
        fewer than 3 nodes none at all (0 rows). ``bidirectional`` False: the forward branch only (a single-branch
        map, whose reverse block mirrors it), columns still over 2N."""
        g, n = self.grid_deg, self.n_nodes
        if n < 3:
            return sp.csr_matrix((0, 2 * n))
        h0, h1 = np.diff(g)[:-1], np.diff(g)[1:]
        share = np.sqrt(0.5 * (h0 + h1))
        coef = np.column_stack([2 / (h0 * (h0 + h1)), -2 / (h0 * h1), 2 / (h1 * (h0 + h1))]) * share[:, None]
        rows = np.repeat(np.arange(n - 2), 3)
        cols = (np.arange(n - 2)[:, None] + np.arange(3)).ravel()
        D = sp.csr_matrix((coef.ravel(), (rows, cols)), shape=(n - 2, n))
        Z = sp.csr_matrix((n - 2, n))
        if not bidirectional:
            return sp.hstack([D, Z], format="csr")
        return sp.vstack([sp.hstack([D, Z]), sp.hstack([Z, D]), sp.hstack([D, -D])], format="csr")

    def weights(self, theta_deg, direction) -> sp.csr_matrix:
        """Sparse interpolation matrix W (K, 2N) with Δθ = W @ values (Eq. 7-9 of 000)."""
        cols, w = self.interpolation(theta_deg, direction)
        k = len(cols)
        return sp.csr_matrix((w.ravel(), cols.ravel(), np.arange(0, 2 * k + 1, 2)), shape=(k, 2 * self.n_nodes))

    def __call__(self, theta_deg, direction) -> np.ndarray:
        """Δθ(θ*, dir) in deg, (K,) -- Eq. (7) of 000 with corrected weights."""
        cols, w = self.interpolation(theta_deg, direction)
        return np.sum(w * self.values[cols], axis=1)

    def to_dict(self) -> dict:
        """The ``error_map.Jn`` object of the result format (formats.md)."""
        return {"grid_deg": self.grid_deg.tolist(),
                "forward_deg": self.forward_deg.tolist(),
                "reverse_deg": self.reverse_deg.tolist()}

    @classmethod
    def from_dict(cls, data: dict, axis: str, outside: str = "error") -> "ErrorMap":
        """Inverse of :meth:`to_dict`; errors name the missing key and the axis."""
        missing = [k for k in ("grid_deg", "forward_deg", "reverse_deg") if k not in data]
        if missing:
            raise ValueError(f"error map {axis}: missing key {missing[0]!r}")
        return cls(data["grid_deg"], data["forward_deg"], data["reverse_deg"],
                   axis=axis, outside=outside)


@dataclass
class Harmonic:
    """One sinusoid of a continuous deviation: amplitude (mdeg), period (deg), phase (deg)."""

    amplitude_mdeg: float = 0.0
    period_deg: float = 360.0
    phase_deg: float = 0.0


@dataclass
class HarmonicDeviation:
    """A continuous deviation truth for simulation: command in, deviation out, same unit.

    Δθ(θ*, dir) = offset + slope·θ* + Σ a_i sin(2π θ*/T_i + φ_i) + dir·(b/2 + b'·θ*/2)

    For a rotary axis (deg): offset and amplitudes in mdeg, slope in mdeg/deg,
    backlash b in mdeg (forward minus reverse deviation) and its trend b' in
    mdeg/deg; gear pitch error gives the harmonics, elastic deformation the
    backlash (000 §4.2 Remark 2). The same type serves a linear axis in mm:
    the "mdeg" fields are then thousandths of a mm, µm (periods in mm), so one
    deviation abstraction covers rotary and linear axes (001 §3).
    """

    offset_mdeg: float = 0.0
    slope_mdeg_per_deg: float = 0.0
    harmonics: List[Harmonic] = field(default_factory=list)
    backlash_mdeg: float = 0.0
    backlash_slope_mdeg_per_deg: float = 0.0

    def __call__(self, theta_deg, direction) -> np.ndarray:
        th = np.asarray(theta_deg, dtype=float).ravel()
        d = _directions(direction, th.size)
        mdeg = self.offset_mdeg + self.slope_mdeg_per_deg * th
        for h in self.harmonics:
            if h.period_deg <= 0:
                raise ValueError(f"harmonic period_deg must be > 0, got {h.period_deg:g}")
            mdeg = mdeg + h.amplitude_mdeg * np.sin(
                2 * np.pi * th / h.period_deg + np.radians(h.phase_deg))
        mdeg = mdeg + d * 0.5 * (self.backlash_mdeg + self.backlash_slope_mdeg_per_deg * th)
        return mdeg * 1e-3


@dataclass
class NoDeviation:
    """A perfect axis: Δθ = 0."""

    def __call__(self, theta_deg, direction) -> np.ndarray:
        th = np.asarray(theta_deg, dtype=float).ravel()
        _directions(direction, th.size)
        return np.zeros_like(th)


def sample_map(deviation, grid_deg, axis: str = "J?") -> ErrorMap:
    """The :class:`ErrorMap` whose nodes equal ``deviation`` at ``grid_deg`` (deg)."""
    g = np.asarray(grid_deg, dtype=float)
    return ErrorMap(g, deviation(g, 1.0), deviation(g, -1.0), axis=axis)
