"""The 21 error motions of a three-axis machine tool (ISO 230-1 names) as one position model.

The machine-tool case of paper 001 (001 §1: "volumetric accuracy" of ISO 230-1)
in 3D: each linear axis k ∈ {X, Y, Z} carries six error motions, smooth
functions of its command q_k, and three squareness errors orient the axes'
reference straight lines. ``docs/machine_3d.md`` states every convention;
in short:

* linear error motions E_Xk, E_Yk, E_Zk in mm (E_kk positioning, the other
  two straightness), angular error motions E_Ak, E_Bk, E_Ck in µrad (rotations
  about the X, Y, Z directions, right-hand rule); squareness E_C0Y (Y to X),
  E_B0Z (Z to X), E_A0Z (Z to Y) in µrad: the rotation of that axis' reference
  straight line about the named direction, right-hand rule;
* every motion is in the tool-relative-to-workpiece sense (what an instrument
  between spindle and table sees);
* representation: a clamped cubic B-spline over the axis travel with a chosen
  knot spacing, linear in its coefficients (the Jacobian w.r.t. a coefficient
  is the basis function times the motion's sensitivity). Gauge fixed in the
  representation: positioning and angular motions are 0 at the travel start
  (their constants trade with a translation, a rotation, the squareness);
  straightness motions are 0 at both travel ends (their reference straight line
  through the end points: a slope is squareness or frame orientation);
* kinematics: the tool point relative to the workpiece is the composition of
  exact homogeneous transforms (no small-angle approximation)
  ``p = A_1(q) A_2(q) … A_n(q) · t_tool`` over the chain (workpiece-side axes
  from the table inward, then tool-side axes outward), with
  ``A_k = Trans(q_k s_k + δ_k(q_k)) · Rx(E_Ak) Ry(E_Bk) Rz(E_Ck)``.

:class:`MachineConfig` is the topology and travel; :class:`VolumetricModel` the
spline model (``positions``, analytic ``jacobian``); :class:`VolumetricPositionModel`
the tool points of a campaign's targets on it, the position model that the
distance measurement of 001 Eq. (3) reads
(:class:`olti_drake.model.measurements.StationDistanceMeasurement`; its Jacobian a
:class:`MotionJacobian`); :func:`synthetic_truth` a seeded truth outside the
basis; :func:`observability` which motions a campaign separates (its distances by
:func:`olti_drake.model.measurements.distance_rows_nd`); :func:`axis_tables`, :func:`error_grid`, :func:`compensate` the
compensation helpers. Units: mm, µrad everywhere in this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Sequence, Tuple

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import BSpline

from olti_drake.formats import VOLUMETRIC_RESULT, result_header
from olti_drake.model.measurements import distance_rows_nd
from olti_drake.model.scara import rows_to_csr
from olti_drake.threads import single_thread_blas

AXES = ("X", "Y", "Z")
#: Per axis, the six error motions in ISO 230-1 order: three linear (mm), three angular (µrad).
COMPONENTS = ("X", "Y", "Z", "A", "B", "C")
SQUARENESS = ("E_C0Y", "E_B0Z", "E_A0Z")
URAD = 1e-6
DEGREE = 3


def motion_names(axis: str) -> Tuple[str, ...]:
    """The six ISO 230-1 names of ``axis``'s error motions: E_X<axis>, …, E_C<axis>."""
    return tuple(f"E_{c}{axis}" for c in COMPONENTS)


ALL_MOTIONS = tuple(n for a in AXES for n in motion_names(a))


def motion_unit(name: str) -> str:
    """'mm' for a linear error motion, 'urad' for an angular one or a squareness."""
    return "mm" if name[2] in "XYZ" and name not in SQUARENESS else "urad"


def motion_role(name: str) -> str:
    """positioning, straightness, roll, pitch, yaw or tilt (Z vertical; docs/machine_3d.md)."""
    c, axis = name[2], name[3]
    if c in "XYZ":
        return "positioning" if c == axis else "straightness"
    if "XYZ"["ABC".index(c)] == axis:
        return "roll"
    if axis == "Z":
        return "tilt"
    return "yaw" if c == "C" else "pitch"


def _fixed_ends(name: str) -> Tuple[bool, bool]:
    """Whether the motion is fixed to 0 at the travel (start, end): the gauge of the representation."""
    return (True, motion_role(name) == "straightness")


# --------------------------------------------------------------------------- configuration
#: The named stackings (``--topology``): (tool_chain, work_chain), each from the machine base outward. serial: X on
#: the base, Y on X, Z on Y; table-xy: the table carries X on Y, the column Z; table-yx: the table carries Y on X,
#: the column Z; table-y: the table carries Y, the column X and the ram Z on X (the A/C trunnion's linear axes,
#: ``models/trunnion_ac.urdf``).
TOPOLOGIES = {"serial": (("X", "Y", "Z"), ()), "table-xy": (("Z",), ("Y", "X")), "table-yx": (("Z",), ("X", "Y")),
              "table-y": (("X", "Z"), ("Y",))}


@dataclass(frozen=True)
class MachineConfig:
    """Topology, travel, knot spacing and tool offsets of a three-axis machine.

    ``tool_chain`` / ``work_chain``: the axes carried by the spindle side and
    by the workpiece (table) side, each listed from the machine base outward:
    a serial X–Y–Z machine (X on the base, Y on X, Z on Y, spindle on Z) is
    ``tool_chain=("X", "Y", "Z"), work_chain=()``; a table carrying X and Y (Y
    on the base, X on Y) with Z on the column is ``tool_chain=("Z",),
    work_chain=("Y", "X")``. ``travel_mm[k]`` = (start, end) of axis k's command
    (mm; the start is the reference position). ``knot_spacing_mm``: the largest
    B-spline knot interval (the travel is split into equal intervals no longer
    than it). ``tool_offsets_mm[m]``: the tool point of tool index m relative to
    the spindle reference point (mm, machine axes), known.
    """

    tool_chain: Tuple[str, ...] = ("X", "Y", "Z")
    work_chain: Tuple[str, ...] = ()
    travel_mm: Dict[str, Tuple[float, float]] = field(
        default_factory=lambda: {"X": (0.0, 400.0), "Y": (0.0, 300.0), "Z": (0.0, 250.0)})
    knot_spacing_mm: float = 50.0
    tool_offsets_mm: Tuple[Tuple[float, float, float], ...] = ((0.0, 0.0, 100.0),)

    def __post_init__(self):
        axes = tuple(self.tool_chain) + tuple(self.work_chain)
        if sorted(axes) != sorted(AXES):
            raise ValueError(f"tool_chain + work_chain must hold X, Y and Z once each, got "
                             f"tool_chain={self.tool_chain!r}, work_chain={self.work_chain!r}")
        for a in AXES:
            try:
                lo, hi = (float(v) for v in self.travel_mm.get(a, (np.nan, np.nan)))
            except (TypeError, ValueError):
                lo = hi = np.nan
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise ValueError(f"travel_mm[{a!r}] must be finite (start, end) with end > start, "
                                 f"got {self.travel_mm.get(a)!r}")
        if not (np.isfinite(self.knot_spacing_mm) and self.knot_spacing_mm > 0):
            raise ValueError(f"knot_spacing_mm must be finite and > 0, got {self.knot_spacing_mm!r}")
        t = np.asarray(self.tool_offsets_mm, float)
        if t.ndim != 2 or t.shape[1] != 3 or not len(t) or not np.all(np.isfinite(t)):
            raise ValueError(f"tool_offsets_mm must be a non-empty list of finite [x, y, z], "
                             f"got {self.tool_offsets_mm!r}")

    @property
    def topology(self) -> str:
        """The name of the stacking (a key of :data:`TOPOLOGIES`, ``--topology``), or '' for an unnamed one."""
        return next((k for k, v in TOPOLOGIES.items() if v == (tuple(self.tool_chain), tuple(self.work_chain))), "")

    @property
    def chain(self) -> Tuple[str, ...]:
        """Links from the workpiece to the tool: the work chain reversed, then the tool chain."""
        return tuple(reversed(self.work_chain)) + tuple(self.tool_chain)

    @property
    def tools(self) -> np.ndarray:
        return np.asarray(self.tool_offsets_mm, float)

    def intervals(self, axis: str) -> int:
        """Knot intervals of ``axis`` (equal, ≤ knot_spacing_mm), counted without making the knots."""
        lo, hi = self.travel_mm[axis]
        return max(1, int(math.ceil((hi - lo) / self.knot_spacing_mm - 1e-9)))

    def knots(self, axis: str) -> np.ndarray:
        """Clamped cubic B-spline knot vector of ``axis`` (mm): equal intervals ≤ knot_spacing_mm."""
        from olti_drake.limits import check_allocation

        lo, hi = self.travel_mm[axis]
        n = self.intervals(axis)
        check_allocation("knot_spacing_mm", f"{self.knot_spacing_mm:g} mm", [n + 1 + 2 * DEGREE],
                         what=f"knots along {axis}", hint="use a larger --knot-spacing-mm")
        inner = np.linspace(lo, hi, n + 1)
        return np.concatenate([[lo] * DEGREE, inner, [hi] * DEGREE])

    def n_basis(self, axis: str) -> int:
        return self.intervals(axis) + DEGREE  # = len(self.knots(axis)) - DEGREE - 1


def _row(k: int, lines=None) -> str:
    """How a row is named in a message: its file line when the caller knows it, else its index."""
    return f"row {k}" if lines is None else f"line {int(lines[k])}"


def check_points(points_mm, tool, n_tools: int, what: str, lines=None):
    """(M, 3) finite points and (M,) tool indices: one-line ValueError naming the row (``lines``: the
    file line of every row) or the indices."""
    c = np.asarray(points_mm, dtype=float)
    c = c.reshape(1, 3) if c.shape == (3,) else c
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"{what}: expected (M, 3) x, y, z in mm, got shape {np.shape(points_mm)}")
    bad = np.flatnonzero(~np.all(np.isfinite(c), axis=1))
    if bad.size:
        raise ValueError(f"{what}: {_row(bad[0], lines)}: {c[bad[0]].tolist()} mm is not finite")
    m = np.zeros(len(c), int) if tool is None else np.broadcast_to(np.asarray(tool), (len(c),))
    if not np.issubdtype(m.dtype, np.integer) or np.any((m < 0) | (m >= n_tools)):
        raise ValueError(f"tool: indices must be integers in 0..{n_tools - 1}, got {np.unique(m)[:5].tolist()}")
    return c, m.astype(int)


def check_commands(config: MachineConfig, commands_mm, tool=None, what: str = "commands", lines=None):
    """(M, 3) commands within the travel and (M,) tool indices: one-line ValueError naming row and axis."""
    c, m = check_points(commands_mm, tool, len(config.tools), what, lines)
    for k, a in enumerate(AXES):
        lo, hi = config.travel_mm[a]
        bad = np.flatnonzero((c[:, k] < lo - 1e-9) | (c[:, k] > hi + 1e-9))
        if bad.size:
            raise ValueError(f"{what}: {_row(bad[0], lines)}: {a.lower()} = {c[bad[0], k]:g} mm is outside the "
                             f"{a} travel [{lo}, {hi}] mm")
    return c, m


class HeldEnds:
    """``motions`` with every motion held at its travel-end value beyond the travel (``--outside clamp``):
    the axis still moves nominally there, its error motions stop changing (derivative 0)."""

    def __init__(self, motions, config: MachineConfig):
        self.inner, self.config = motions, config
        self.squareness_urad = motions.squareness_urad
        self.tool_offset_errors_mm = motions.tool_offset_errors_mm

    def evaluate(self, axis: str, q, derivative: int = 0) -> np.ndarray:
        lo, hi = self.config.travel_mm[axis]
        q = np.asarray(q, float)
        v = self.inner.evaluate(axis, np.clip(q, lo, hi), derivative)
        return np.where(((q < lo) | (q > hi))[:, None], 0.0, v) if derivative else v


def predict_positions(config: MachineConfig, motions, commands_mm, tool=None, outside: str = "error",
                      lines=None) -> np.ndarray:
    """Actual tool points (M, 3) mm for commands (M, 3) mm; ``outside``: 'error' refuses a command beyond
    the travel (one line naming its row or file line), 'clamp' holds the motions at the travel ends."""
    if outside == "clamp":
        c, m = check_points(commands_mm, tool, len(config.tools), "commands", lines)
        return chain_state(config, HeldEnds(motions, config), c, m).p
    if outside != "error":
        raise ValueError(f"outside must be 'error' or 'clamp', got {outside!r}")
    c, m = check_commands(config, commands_mm, tool, "commands", lines)
    return chain_state(config, motions, c, m).p


def clamp_commands(config: MachineConfig, commands_mm) -> np.ndarray:
    """Commands (M, 3) mm moved into the travel box (each axis clipped to its [start, end])."""
    lo = [config.travel_mm[a][0] for a in AXES]
    hi = [config.travel_mm[a][1] for a in AXES]
    return np.clip(np.asarray(commands_mm, float), lo, hi)


# --------------------------------------------------------------------------- error motions
def _real(values) -> np.ndarray:
    """``values`` as a float array, or as the object array it is (AutoDiffXd entries: the Drake systems
    differentiate the kinematics of this module, :class:`~olti_drake.sim.systems.VolumetricTool`)."""
    a = np.asarray(values)
    return a if a.dtype == object else a.astype(float)


def _values(a) -> np.ndarray:
    """The float values of a float or object (AutoDiffXd) array."""
    if a.dtype != object:
        return a
    return np.array([v.value() if hasattr(v, "value") else float(v) for v in a.ravel()]).reshape(a.shape)


def _offset_errors(config: MachineConfig, errors_mm) -> np.ndarray:
    """(n_tools, 3) tool-offset errors mm; tool 0's must be 0 (it is the origin's translation)."""
    e = np.zeros((len(config.tools), 3)) if errors_mm is None else _real(errors_mm)
    if e.shape != (len(config.tools), 3) or not np.all(np.isfinite(_values(e))) or np.any(_values(e)[0] != 0):
        raise ValueError(f"tool_offset_errors_mm: expected {len(config.tools)} finite [dx, dy, dz] with tool 0's "
                         f"= 0, got {np.asarray(errors_mm).tolist()}")
    return e


class SplineMotions:
    """Error motions on the cubic B-spline basis of :class:`MachineConfig` (the identified model).

    ``coefficients[name]`` holds every B-spline coefficient of that motion (mm or
    µrad; the fixed ones are 0); ``squareness_urad`` = (E_C0Y, E_B0Z, E_A0Z);
    ``tool_offset_errors_mm`` (n_tools, 3): actual minus configured tool offsets (0: known offsets).
    """

    def __init__(self, config: MachineConfig, coefficients: Dict[str, np.ndarray], squareness_urad,
                 tool_offset_errors_mm=None):
        self.config = config
        self.coefficients = coefficients
        self.squareness_urad = _real(squareness_urad)
        self.tool_offset_errors_mm = _offset_errors(config, tool_offset_errors_mm)
        self._splines = {a: BSpline(config.knots(a), np.eye(config.n_basis(a)), DEGREE, extrapolate=True)
                         for a in AXES}
        self._slopes = {a: s.derivative() for a, s in self._splines.items()}

    def basis(self, axis: str, q, derivative: int = 0) -> np.ndarray:
        """(M, n_basis) B-spline basis of ``axis`` at q (mm), or its first derivative (1/mm)."""
        return (self._slopes if derivative else self._splines)[axis](np.asarray(q, float))

    def evaluate(self, axis: str, q, derivative: int = 0) -> np.ndarray:
        """(M, 6) the six motions of ``axis`` at q (mm / µrad), or their derivative in q (per mm)."""
        b = self.basis(axis, q, derivative)
        return np.column_stack([b @ self.coefficients[n] for n in motion_names(axis)])


class SineMotions:
    """A synthetic truth outside the spline basis: sums of sines, under the same gauge conventions.

    Per motion, Σ_i a_i sin(2π q / P_i + φ_i) minus its value at the travel
    start (positioning, angular) or minus the chord through both ends
    (straightness) -- so the truth obeys the conventions of the
    representation and is recoverable up to the basis approximation error.
    ``terms[name]`` = (amplitudes, periods mm, phases rad).
    """

    def __init__(self, config: MachineConfig, terms: Dict[str, Tuple[np.ndarray, np.ndarray, np.ndarray]],
                 squareness_urad, tool_offset_errors_mm=None):
        self.config = config
        self.terms = terms
        self.squareness_urad = np.asarray(squareness_urad, float)
        self.tool_offset_errors_mm = _offset_errors(config, tool_offset_errors_mm)

    def _raw(self, name, q, derivative):
        a, period, phase = self.terms[name]
        w = 2 * np.pi / period
        arg = np.multiply.outer(np.asarray(q, float), w) + phase
        return (np.sin(arg) * a).sum(-1) if not derivative else (np.cos(arg) * a * w).sum(-1)

    def _one(self, name, q, derivative):
        lo, hi = self.config.travel_mm[name[3]]
        g0, g1 = self._raw(name, np.array([lo, hi]), 0)
        slope = (g1 - g0) / (hi - lo) if _fixed_ends(name)[1] else 0.0
        if derivative:
            return self._raw(name, q, 1) - slope
        return self._raw(name, q, 0) - g0 - slope * (np.asarray(q, float) - lo)

    def evaluate(self, axis: str, q, derivative: int = 0) -> np.ndarray:
        return np.column_stack([self._one(n, q, derivative) for n in motion_names(axis)])

    def spline_error_bound(self, config: MachineConfig) -> Dict[str, float]:
        """Per motion, the a-priori distance (mm or µrad) of this truth from ``config``'s spline space:
        (5/384) h⁴ ‖f⁗‖∞ (cubic spline interpolation error, h the knot interval; the subtracted
        chord is linear and does not change f⁗), with ‖f⁗‖∞ ≤ Σ |a_i| (2π/P_i)⁴."""
        out = {}
        for name, (a, period, _) in self.terms.items():
            lo, hi = config.travel_mm[name[3]]
            h = (hi - lo) / (config.n_basis(name[3]) - DEGREE)
            out[name] = 5.0 / 384.0 * h ** 4 * float(np.sum(np.abs(a) * (2 * np.pi / period) ** 4))
        return out


def synthetic_truth(config: MachineConfig, seed: int, amplitude_mm: float = 0.005,
                    amplitude_urad: float = 10.0, squareness_urad=(12.0, -8.0, 5.0),
                    min_period_intervals: float = 4.0, tool_offset_errors_mm=None) -> SineMotions:
    """Seeded truth motions: per motion two sines, periods between ``min_period_intervals`` knot
    intervals and 1.5 travels (so never a knot multiple by construction), amplitudes up to
    ``amplitude_mm`` (linear) or ``amplitude_urad`` (angular), random phases; squareness given (µrad).
    The positioning motions also get a scale error of ±20 µm/m. ``tool_offset_errors_mm``: the true
    offsets minus the configured ones (tool 0's = 0)."""
    rng = np.random.default_rng(seed)
    terms = {}
    for name in ALL_MOTIONS:
        axis = name[3]
        lo, hi = config.travel_mm[axis]
        h = (hi - lo) / (config.n_basis(axis) - DEGREE)
        amp = amplitude_mm if motion_unit(name) == "mm" else amplitude_urad
        periods = rng.uniform(min_period_intervals * h, 1.5 * (hi - lo), size=2)
        a = amp * rng.uniform(0.3, 1.0, size=2)
        phase = rng.uniform(0, 2 * np.pi, size=2)
        if motion_role(name) == "positioning":  # a scale error: one very long sine ≈ slope
            scale = rng.uniform(-20e-6, 20e-6)
            long_period = 40.0 * (hi - lo)
            a = np.append(a, scale * long_period / (2 * np.pi))
            periods, phase = np.append(periods, long_period), np.append(phase, 0.0)
        terms[name] = (a, periods, phase)
    return SineMotions(config, terms, squareness_urad, tool_offset_errors_mm)


# --------------------------------------------------------------------------- kinematics
def _rotations(e_rad):
    """R = Rx(a) Ry(b) Rz(c) (M, 3, 3) and its derivatives dR/da, dR/db, dR/dc, e = (a, b, c) rad."""
    m = e_rad.shape[0]
    c, s = np.cos(e_rad), np.sin(e_rad)
    one, zero = np.ones(m), np.zeros(m)

    def mats(rows):
        return np.stack([np.stack(r, -1) for r in rows], -2)

    rx = mats([(one, zero, zero), (zero, c[:, 0], -s[:, 0]), (zero, s[:, 0], c[:, 0])])
    ry = mats([(c[:, 1], zero, s[:, 1]), (zero, one, zero), (-s[:, 1], zero, c[:, 1])])
    rz = mats([(c[:, 2], -s[:, 2], zero), (s[:, 2], c[:, 2], zero), (zero, zero, one)])
    drx = mats([(zero, zero, zero), (zero, -s[:, 0], -c[:, 0]), (zero, c[:, 0], -s[:, 0])])
    dry = mats([(-s[:, 1], zero, c[:, 1]), (zero, zero, zero), (-c[:, 1], zero, -s[:, 1])])
    drz = mats([(-s[:, 2], -c[:, 2], zero), (c[:, 2], -s[:, 2], zero), (zero, zero, zero)])
    ryz = ry @ rz
    return rx @ ryz, (drx @ ryz, rx @ dry @ rz, rx @ ry @ drz)


def axis_directions(squareness_urad) -> Dict[str, Tuple[np.ndarray, Tuple[np.ndarray, ...]]]:
    """Unit direction s_k of each axis' reference straight line and ds_k/d(E_C0Y, E_B0Z, E_A0Z) per rad.

    X defines the x direction; s_Y = Rz(E_C0Y) e_y; s_Z = Ry(E_B0Z) Rx(E_A0Z) e_z
    (exact rotations of the nominal directions, right-hand rule).
    """
    c, b, a = _real(squareness_urad) * URAD
    zero = np.zeros(3)
    s_y = np.array([-np.sin(c), np.cos(c), 0.0])
    ds_y = (np.array([-np.cos(c), -np.sin(c), 0.0]), zero, zero)
    s_z = np.array([np.cos(a) * np.sin(b), -np.sin(a), np.cos(a) * np.cos(b)])
    ds_z = (zero, np.array([np.cos(a) * np.cos(b), 0.0, -np.cos(a) * np.sin(b)]),
            np.array([-np.sin(a) * np.sin(b), -np.cos(a), -np.sin(a) * np.cos(b)]))
    return {"X": (np.array([1.0, 0.0, 0.0]), (zero, zero, zero)), "Y": (s_y, ds_y), "Z": (s_z, ds_z)}


@dataclass
class ChainState:
    """Everything the Jacobians need from one pass over the chain (per link, in chain order)."""

    p: np.ndarray                      # (M, 3) tool point, mm
    C: list                            # C_k (M, 3, 3): rotation of the links before k; C[n]: all
    v_next: list                       # v_{k+1} (M, 3): the tool point from link k's origin, before R_k
    dR: list                           # dR_k/d(a, b, c) per rad, 3 × (M, 3, 3)
    q: Dict[str, np.ndarray]


def chain_state(config: MachineConfig, motions, commands_mm, tool) -> ChainState:
    """Forward pass of p = A_1 ⋯ A_n t over the chain (exact rotations), commands (M, 3) mm."""
    c = np.asarray(commands_mm, float)
    m = np.asarray(tool, int)
    t = config.tools[m] + motions.tool_offset_errors_mm[m]
    dirs = axis_directions(motions.squareness_urad)
    chain = config.chain
    q = {a: c[:, AXES.index(a)] for a in AXES}
    links = []
    for a in chain:
        e = motions.evaluate(a, q[a])
        R, dR = _rotations(e[:, 3:] * URAD)
        links.append((q[a][:, None] * dirs[a][0] + e[:, :3], R, dR))
    v, v_next = t, [None] * len(chain)
    for k in range(len(chain) - 1, -1, -1):
        v_next[k] = v
        o, R, _ = links[k]
        v = o + np.einsum("mij,mj->mi", R, v)
    C, acc = [], np.broadcast_to(np.eye(3), (len(c), 3, 3))
    for o, R, _ in links:
        C.append(acc)
        acc = acc @ R
    C.append(acc)
    return ChainState(v, C, v_next, [dR for _, _, dR in links], q)


def motion_sensitivities(state: ChainState, chain: Sequence[str]) -> Dict[str, np.ndarray]:
    """∂p/∂(motion value) (M, 3) per error motion: mm/mm for linear, mm/µrad for angular."""
    out = {}
    for k, a in enumerate(chain):
        Ck = state.C[k]
        for r, name in enumerate(motion_names(a)):
            if r < 3:
                out[name] = Ck[:, :, r]
            else:
                g = np.einsum("mij,mj->mi", state.dR[k][r - 3], state.v_next[k])
                out[name] = np.einsum("mij,mj->mi", Ck, g) * URAD
    return out


def command_jacobian(config: MachineConfig, motions, state: ChainState) -> np.ndarray:
    """∂p/∂(x, y, z command) (M, 3, 3), mm/mm: s_k + δ_k'(q) + rotation rate × downstream arm."""
    dirs = axis_directions(motions.squareness_urad)
    out = np.empty((len(state.p), 3, 3))
    for k, a in enumerate(config.chain):
        de = motions.evaluate(a, state.q[a], derivative=1)
        arm = sum(np.einsum("mij,mj->mi", state.dR[k][r], state.v_next[k]) * (de[:, 3 + r, None] * URAD)
                  for r in range(3))
        local = dirs[a][0] + de[:, :3] + arm
        out[:, :, AXES.index(a)] = np.einsum("mij,mj->mi", state.C[k], local)
    return out


def tool_positions(config: MachineConfig, motions, commands_mm, tool=None) -> np.ndarray:
    """Actual tool point (M, 3) mm relative to the workpiece for commands (M, 3) mm and tool indices."""
    c, m = check_commands(config, commands_mm, tool)
    return chain_state(config, motions, c, m).p


# --------------------------------------------------------------------------- the spline model
class VolumetricModel:
    """The identified model: B-spline coefficients of the 18 error motions and the 3 squareness errors.

    Parameter vector layout (``parameter_names()``): per axis X, Y, Z, per motion
    in ISO order (E_X?, E_Y?, E_Z?, E_A?, E_B?, E_C?), the free B-spline
    coefficients ``E_XX[j]`` (j = B-spline index; mm or µrad), then
    ``E_C0Y_urad``, ``E_B0Z_urad``, ``E_A0Z_urad``. The coefficients fixed by the
    gauge (index 0 of every motion, and the last index of the straightness
    motions) are not parameters: they are 0.

    ``identify_tool_offsets``: also the errors of the tool offsets of tools
    1, 2, … (``tool1_x_mm``, ``tool1_y_mm``, ``tool1_z_mm``, …; mm, added to the
    configured offsets): a reflector's mounting position is known to a fraction
    of a mm only, and its error would otherwise bias the error motions. Tool
    0's offset error is a translation of the origin (fixed at 0).
    """

    def __init__(self, config: MachineConfig, identify_tool_offsets: bool = False):
        self.config = config
        self.identify_tool_offsets = bool(identify_tool_offsets)
        self.free: Dict[str, np.ndarray] = {}
        self.slices: Dict[str, slice] = {}
        start = 0
        for name in ALL_MOTIONS:
            n = config.n_basis(name[3])
            fix0, fix1 = _fixed_ends(name)
            idx = np.arange(int(fix0), n - int(fix1))
            self.free[name] = idx
            self.slices[name] = slice(start, start + len(idx))
            start += len(idx)
        for name in SQUARENESS:
            self.slices[name] = slice(start, start + 1)
            start += 1
        self.tool_groups = tuple(f"tool{m}" for m in range(1, len(config.tools))) if identify_tool_offsets else ()
        for name in self.tool_groups:
            self.slices[name] = slice(start, start + 3)
            start += 3
        self.n_params = start

    def parameter_names(self) -> Tuple[str, ...]:
        names = [f"{m}[{j}]" for m in ALL_MOTIONS for j in self.free[m]]
        tools = [f"{g}_{c}_mm" for g in self.tool_groups for c in "xyz"]
        return tuple(names) + tuple(f"{s}_urad" for s in SQUARENESS) + tuple(tools)

    def zeros(self) -> np.ndarray:
        return np.zeros(self.n_params)

    def motions(self, params) -> SplineMotions:
        """The :class:`SplineMotions` of a parameter vector (float, or AutoDiffXd: its motions and the
        tool points of :func:`tool_positions` then carry the derivatives)."""
        x = _real(params)
        if x.shape != (self.n_params,):
            raise ValueError(f"params: expected {self.n_params} values, got shape {x.shape}")
        coef = {}
        for name in ALL_MOTIONS:
            full = np.zeros(self.config.n_basis(name[3]), dtype=x.dtype)
            full[self.free[name]] = x[self.slices[name]]
            coef[name] = full
        offsets = np.zeros((len(self.config.tools), 3), dtype=x.dtype)
        for m, g in enumerate(self.tool_groups, start=1):
            offsets[m] = x[self.slices[g]]
        return SplineMotions(self.config, coef, [x[self.slices[s]][0] for s in SQUARENESS], offsets)

    def parameters_of(self, motions: SplineMotions) -> np.ndarray:
        """The parameter vector of spline ``motions`` on this model's basis (the inverse of :meth:`motions`);
        one-line ValueError for motions outside the representation (another basis, a gauge-fixed
        coefficient not 0, an offset error of a tool whose offset this model does not identify)."""
        x = self.zeros()
        for name in ALL_MOTIONS:
            c = np.asarray(motions.coefficients[name], float)
            if c.shape != (self.config.n_basis(name[3]),):
                raise ValueError(f"{name}: {c.size} B-spline coefficients, this model's basis has "
                                 f"{self.config.n_basis(name[3])}")
            fixed = np.setdiff1d(np.arange(c.size), self.free[name])
            if np.any(c[fixed] != 0):
                raise ValueError(f"{name}: coefficient(s) {fixed[c[fixed] != 0].tolist()} are fixed to 0 by the "
                                 f"gauge of the representation, got {c[fixed][c[fixed] != 0].tolist()}")
            x[self.slices[name]] = c[self.free[name]]
        for s in SQUARENESS:
            x[self.slices[s]] = float(motions.squareness_urad[SQUARENESS.index(s)])
        offsets = np.asarray(motions.tool_offset_errors_mm, float)
        for m, g in enumerate(self.tool_groups, start=1):
            x[self.slices[g]] = offsets[m]
        if not self.tool_groups and np.any(offsets != 0):
            raise ValueError("tool offset errors given, but this model does not identify tool offsets")
        return x

    def positions(self, commands_mm, tool, params) -> np.ndarray:
        """Actual tool positions (M, 3) mm for commands (M, 3) mm and tool indices (M,)."""
        return tool_positions(self.config, self.motions(params), commands_mm, tool)

    def jacobian(self, commands_mm, tool, params):
        """Positions (M, 3) mm and their Jacobian (M, 3, n_params) w.r.t. every parameter, analytic.

        A coefficient's column is the motion's sensitivity (mm/mm or mm/µrad)
        times its basis function at the axis command; a squareness column is
        C_k q_k ds_k/dθ (mm/µrad); a tool-offset column is the rotation of the
        whole chain (rows of that tool only). Exact for the exact-rotation chain.
        """
        c, m = check_commands(self.config, commands_mm, tool)
        motions = self.motions(params)
        state = chain_state(self.config, motions, c, m)
        sens = motion_sensitivities(state, self.config.chain)
        J = np.zeros((len(c), 3, self.n_params))
        bases = {a: motions.basis(a, state.q[a]) for a in AXES}
        for name in ALL_MOTIONS:
            J[:, :, self.slices[name]] = sens[name][:, :, None] * bases[name[3]][:, None, self.free[name]]
        dirs = axis_directions(motions.squareness_urad)
        chain = self.config.chain
        for r, (name, axis) in enumerate(zip(SQUARENESS, ("Y", "Z", "Z"))):
            k = chain.index(axis)
            ds = dirs[axis][1][r] * URAD
            J[:, :, self.slices[name].start] = np.einsum("mij,j->mi", state.C[k], ds) * state.q[axis][:, None]
        for g in self.tool_groups:
            rows = m == int(g[4:])
            J[rows, :, self.slices[g]] = state.C[-1][rows]
        return state.p, J

    def fit_function(self, motions, n_samples: int = 400) -> np.ndarray:
        """Parameters whose splines best approximate ``motions`` (least squares on a dense grid per
        motion, same gauge); squareness copied. The basis-approximation reference of the tests."""
        x = self.zeros()
        for name in ALL_MOTIONS:
            a = name[3]
            lo, hi = self.config.travel_mm[a]
            q = np.linspace(lo, hi, n_samples)
            B = self.motions(self.zeros()).basis(a, q)[:, self.free[name]]
            y = motions.evaluate(a, q)[:, motion_names(a).index(name)]
            x[self.slices[name]] = np.linalg.lstsq(B, y, rcond=None)[0]
        for s in SQUARENESS:
            x[self.slices[s]] = motions.squareness_urad[SQUARENESS.index(s)]
        for m, g in enumerate(self.tool_groups, start=1):
            x[self.slices[g]] = motions.tool_offset_errors_mm[m]
        return x


# --------------------------------------------------------------------------- the position model
#: A linear error motion beyond this (mm), or an angular one beyond this (µrad), is no machine's: wrong units.
IMPLAUSIBLE_MM, IMPLAUSIBLE_URAD = 1.0, 1e4


@dataclass(frozen=True, eq=False)
class MotionJacobian:
    """∂p/∂x of M tool points, row-compressed: coordinate c of point k moves with column ``cols[k, j]`` by
    ``vals[k, c, j]`` (mm/mm for a linear motion's coefficient or a tool offset, mm/µrad for an angular one or a
    squareness), over ``n_params`` columns. The conventions of
    :class:`olti_drake.model.free_points.FreePointJacobian` (and of the serial model's ``PositionJacobian``):
    :meth:`tocsr` rows x, y, z of point 0, then point 1, ...; :meth:`contract` for distance rows."""

    cols: np.ndarray
    vals: np.ndarray
    n_params: int

    def tocsr(self, extra_vals=None, extra_cols=None, n_cols=None):
        """The (3 M, n_cols) sparse Jacobian, rows x, y, z of point 0, then point 1, ..., plus per-row extra
        entries (``extra_vals``/``extra_cols`` (3 M, e): a measurement's own parameters, columns ≥ n_params)."""
        M, D, m = self.vals.shape
        cols, vals = np.repeat(self.cols, D, axis=0), self.vals.reshape(D * M, m)
        return _motion_csr(cols, vals, extra_vals, extra_cols, n_cols or self.n_params)

    def contract(self, u, extra_vals=None, extra_cols=None, n_cols=None):
        """(M, n_cols) sparse rows u_k · ∂p_k/∂x (u (M, 3)), plus per-row extra entries (a measurement's own
        parameters, columns ≥ n_params)."""
        u = np.asarray(u, dtype=float)
        vals = u[:, :1] * self.vals[:, 0] + u[:, 1:2] * self.vals[:, 1] + u[:, 2:3] * self.vals[:, 2]
        return _motion_csr(self.cols, vals, extra_vals, extra_cols, n_cols or self.n_params)

    def take(self, index) -> "MotionJacobian":
        """The Jacobian of the points ``index`` (e.g. the target of every reading)."""
        return MotionJacobian(self.cols[index], self.vals[index], self.n_params)


def _motion_csr(cols, vals, extra_vals, extra_cols, n_cols):
    # Fresh arrays: the matrix may keep them, and summing its duplicates works in place.
    if extra_vals is not None:
        cols, vals = np.hstack([cols, extra_cols]), np.hstack([vals, extra_vals])
    else:
        cols, vals = np.array(cols), np.array(vals)
    jac = rows_to_csr(cols, vals, n_cols)
    jac.sum_duplicates()  # a point's padding repeats its first column (value 0)
    return jac


class VolumetricPositionModel:
    """The tool points of a campaign's targets on the volumetric model, as a position model: target i is the
    tool point p_i = p(q_i, t_m; θ) (mm) of command q_i = ``commands_mm[i]`` (x, y, z mm) with tool m =
    ``tool[i]``, the exact-rotation chain of :class:`VolumetricModel` over the 21 ISO 230-1 motions
    (E_XX … E_CZ), the squareness E_C0Y, E_B0Z, E_A0Z and the tool-offset errors (docs/machine_3d.md).

    It offers what :class:`olti_drake.model.measurements.StationDistanceMeasurement` reads (001 Eq. (3): r =
    ‖p_i − P_j‖ − L0_j − ΔL) -- ``names``, ``n_params``, ``dim``, ``start_vector()``, ``positions(x)``, the
    batched :meth:`rows`, :meth:`layout`, :meth:`implausible`, :meth:`station_reference` -- and :meth:`jacobian` in the
    sparse convention of the free points of 001 (:class:`MotionJacobian`).

    Parameters x (``names``): the parameters of ``model`` (``VolumetricModel.parameter_names()``: free B-spline
    coefficients in mm or µrad, squareness in µrad, tool-offset errors in mm) less the motions in ``held``: those
    are no unknowns, held at 0 (which ones is the campaign's observability, decided before the model is built:
    :func:`olti_drake.estimation.volumetric.separable_motions`). :attr:`free_cols` maps x into the model's
    vector (:meth:`theta`). The start is θ = 0 (the nominal machine).

    Each point's Jacobian columns are those its B-spline bases reach at its command (4 per motion at most), the
    squareness and its own tool's offset error: fixed by the commands, not by x (the Monte Carlo's batched rows
    share them). Units: mm, µrad.
    """

    dim = 3

    def __init__(self, model: VolumetricModel, commands_mm, tool, held: Sequence[str] = ()):
        self.model = model
        self.config = model.config
        self.commands_mm = np.asarray(commands_mm, dtype=float)
        self.tool = np.asarray(tool, dtype=int)
        self.held = tuple(held)
        held_cols = np.zeros(model.n_params, bool)
        for g in self.held:
            held_cols[model.slices[g]] = True
        self.free_cols = np.flatnonzero(~held_cols)
        every = model.parameter_names()
        self.names: Tuple[str, ...] = tuple(every[i] for i in self.free_cols)
        self._cols, self._full_cols, self._padding = self._pattern()

    @property
    def n_points(self) -> int:
        return len(self.commands_mm)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def _pattern(self):
        """Per point, the columns (of x; of the model's vector) its position may depend on, ascending, padded to
        one width by repeating the point's first column; and where the padding is."""
        model = self.model
        touch = np.zeros((self.n_points, model.n_params), bool)
        bases = model.motions(model.zeros())
        for name in ALL_MOTIONS:
            axis = name[3]
            b = bases.basis(axis, self.commands_mm[:, AXES.index(axis)])
            touch[:, model.slices[name]] = b[:, model.free[name]] != 0
        for name in SQUARENESS:
            touch[:, model.slices[name]] = True
        for g in model.tool_groups:
            touch[self.tool == int(g[4:]), model.slices[g]] = True
        touch = touch[:, self.free_cols]
        count = touch.sum(axis=1)
        width = max(int(count.max(initial=0)), 1)
        order = np.argsort(~touch, axis=1, kind="stable")[:, :width]  # the touched columns first, ascending
        padding = np.arange(width)[None, :] >= count[:, None]
        cols = np.where(padding, order[:, :1], order)
        return cols, self.free_cols[cols], padding

    def start_vector(self) -> np.ndarray:
        """θ = 0: every free coefficient, squareness and tool-offset error 0 (the nominal machine)."""
        return np.zeros(self.n_params)

    def theta(self, x) -> np.ndarray:
        """The model's full parameter vector (held motions 0) from x (its first :attr:`n_params` values)."""
        t = self.model.zeros()
        t[self.free_cols] = np.asarray(x, dtype=float)[:self.n_params]
        return t

    def positions(self, x=None) -> np.ndarray:
        """The tool points (N, 3) mm at x (default the start)."""
        return self.model.positions(self.commands_mm, self.tool, self.theta(self.start_vector() if x is None else x))

    def _compressed(self, theta):
        p, J = self.model.jacobian(self.commands_mm, self.tool, theta)
        vals = np.take_along_axis(J, self._full_cols[:, None, :], axis=2)
        vals[np.broadcast_to(self._padding[:, None, :], vals.shape)] = 0.0
        return p, vals

    def jacobian(self, x=None):
        """The tool points (N, 3) mm and their :class:`MotionJacobian` over ``names`` (analytic,
        :meth:`VolumetricModel.jacobian`)."""
        p, vals = self._compressed(self.theta(self.start_vector() if x is None else x))
        return p, MotionJacobian(self._cols, vals, self.n_params)

    def rows(self, X, points):
        """The points read, batched, row-compressed (for :func:`~olti_drake.model.measurements.distance_rows_nd`).

        Args:
            X: (T, n ≥ n_params) parameter vectors (the model's first), mm / µrad.
            points: (K,) the point (target) of every reading.

        Returns:
            p (T, K, 3) mm; cols (K, m) the parameter columns of p_points[k]; dp: per coordinate c the (T, K, m)
            ∂p_c on those columns (mm/mm, mm/µrad).
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        p = np.empty((len(X), self.n_points, 3))
        vals = np.empty((len(X), self.n_points, 3, self._cols.shape[1]))
        for t, x in enumerate(X):
            p[t], vals[t] = self._compressed(self.theta(x))
        vals = vals[:, points]
        return p[:, points], self._cols[points], tuple(vals[:, :, c] for c in range(3))

    def roughness(self):
        """The smoothness prior's rows over :attr:`names` (issue 23; its weight the engine's,
        :meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.smoothing_weight`):
        :func:`motion_roughness` of the identified (not held) motions, at the lever
        :meth:`roughness_lever_mm`."""
        cols = np.full(self.model.n_params, -1)
        cols[self.free_cols] = np.arange(self.n_params)
        R = motion_roughness(self.model, self.roughness_lever_mm())
        keep = cols >= 0
        R = R[:, keep]
        R = R[np.asarray(abs(R).sum(axis=1)).ravel() > 0]
        return R.tocsr() if R.shape[0] else None

    def roughness_lever_mm(self) -> float:
        """:func:`roughness_lever_mm` of the commands (mm)."""
        return roughness_lever_mm(self.commands_mm)

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values or uncertainties) as result.json's ``model``: the model's full vector
        (``VolumetricModel.parameter_names()``; held motions 0)."""
        return {"model": self.theta(v).tolist()}

    def station_reference(self):
        """(centre mm, span mm, its name) that a station's plausibility is judged by: the command centroid and
        the travel diagonal of the commands."""
        c = self.commands_mm
        return c.mean(axis=0), float(np.linalg.norm(np.ptp(c, axis=0))), "the travel diagonal"

    def implausible(self, x) -> list:
        """Motion values no machine has (a linear motion over :data:`IMPLAUSIBLE_MM` mm, an angular one over
        :data:`IMPLAUSIBLE_URAD` µrad, anywhere on the travel), one phrase each (empty: plausible)."""
        motions = self.model.motions(self.theta(x))
        out = []
        for a in AXES:
            v = motions.evaluate(a, np.linspace(*self.config.travel_mm[a], 101))
            for r, name in enumerate(motion_names(a)):
                limit = IMPLAUSIBLE_MM if r < 3 else IMPLAUSIBLE_URAD
                if np.abs(v[:, r]).max() > limit:
                    out.append(f"{name} reaches {np.abs(v[:, r]).max():.6g} {motion_unit(name)} (over {limit:g})")
        return out


def roughness_lever_mm(commands_mm) -> float:
    """The lever (mm) at which an angular motion's roughness counts as the tool point's: half the commands'
    travel diagonal (ε µrad turns a point that far away by ε·lever·10⁻⁶ mm)."""
    return 0.5 * float(np.linalg.norm(np.ptp(np.asarray(commands_mm, float), axis=0))) or 1.0


def motion_roughness(model: VolumetricModel, lever_mm: float) -> sp.csr_matrix:
    """Rows R over the model's parameter vector with ‖R θ‖² = Σ_motions s² ∫ f''(q)² dq over each motion's
    travel (f = Σ c_j B_j its B-spline): exact, f'' of a cubic B-spline being piecewise linear, by two
    Gauss-Legendre points per knot interval. s = 1 for a linear motion (mm); lever_mm·10⁻⁶ for an angular one
    (µrad): its roughness counted at the tool point it moves, so that one weight serves mm and µrad alike.
    Squareness and tool offsets: no rows (constants). Units: mm/mm² · √mm."""
    splines = model.motions(model.zeros())
    nodes, weights = np.polynomial.legendre.leggauss(2)
    blocks = []
    for name in ALL_MOTIONS:
        axis, sl = name[3], model.slices[name]
        inner = np.unique(model.config.knots(axis))
        h = np.diff(inner)
        q = (inner[:-1, None] + 0.5 * h[:, None] * (1.0 + nodes[None, :])).ravel()
        w = (0.5 * h[:, None] * weights[None, :]).ravel()
        scale = lever_mm * URAD if motion_unit(name) == "urad" else 1.0
        b2 = splines._splines[axis].derivative(2)(q)[:, model.free[name]] * (np.sqrt(w)[:, None] * scale)
        block = np.zeros((len(q), model.n_params))
        block[:, sl] = b2
        blocks.append(sp.csr_matrix(block))
    return sp.vstack(blocks, format="csr")


# --------------------------------------------------------------------------- observability
@dataclass(frozen=True)
class MotionObservability:
    """Per error motion (squareness, identified tool offset ``tool<m>``): separable or not, and
    the motions (and nuisances) it trades with."""

    separable: Dict[str, bool]
    trades_with: Dict[str, Tuple[str, ...]]
    null_dimension: int
    singular_values: np.ndarray
    rtol: float
    measurement: str
    #: Motions taken out of the campaign's unknowns (held at 0) before the check: not in the other fields.
    held: Tuple[str, ...] = ()

    @property
    def inseparable(self) -> Tuple[str, ...]:
        return tuple(n for n, ok in self.separable.items() if not ok)

    def describe(self) -> str:
        """One line per motion the campaign cannot separate, naming what it trades with."""
        if not self.inseparable:
            tools = [n for n in self.separable if n.startswith("tool")]
            extra = f" and {len(tools)} tool offsets" if tools else ""
            held = f", {', '.join(self.held)} held at 0" if self.held else ""
            return (f"all {len(self.separable) - len(tools)} error motions{extra} separable ({self.measurement}; "
                    f"rtol {self.rtol:g}{held})")
        return "\n".join(f"{n}: not separable, " + (f"trades with {', '.join(self.trades_with[n])}"
                                                    if self.trades_with[n] else "no reading depends on it")
                         for n in self.inseparable)


def _rigid_columns(p) -> np.ndarray:
    """(3M, 6) Jacobian of points p under a small rigid motion: translation (mm), rotation (rad)."""
    m = len(p)
    out = np.zeros((m, 3, 6))
    out[:, :, :3] = np.eye(3)
    for k, e in enumerate(np.eye(3)):
        out[:, :, 3 + k] = np.cross(e, p)
    return out.reshape(3 * m, 6)


def observability(model: VolumetricModel, commands_mm, tool, stations_mm=None, params=None,
                  rtol: float = 1e-8, share: float = 1e-3, held: Sequence[str] = (),
                  prior=None) -> MotionObservability:
    """Which of the 21 error motions a campaign layout separates (up to the representation's gauge).

    Measurement: 3D target positions in an unknown frame (``stations_mm`` None:
    a rigid 6-dof gauge) or distances ‖p_i − P_j‖ − d0_j from every station
    (unknown stations P_j and dead paths d0_j: 001 Eq. (3) in 3D; the rigid
    gauge is then among the stations' freedoms). The model Jacobian, columns
    scaled to unit norm, is projected off the nuisance columns; its SVD gives
    the null space (singular values ≤ ``rtol`` × largest). A motion is separable
    when the null space has no more than ``share`` of its coefficient block
    (2-norm of the block of the orthonormal null basis); an inseparable one is
    reported with the motions sharing its null directions ("gauge" when the
    nuisance columns take part). ``held``: motions (or ``tool<m>`` groups) taken out of the
    unknowns, as held at 0: their columns are dropped and they are not reported. ``prior``: rows of a
    prior over the model's parameters (the smoothness prior, :func:`motion_roughness`), stacked under the
    projected readings: the directions it determines are no null directions (its weight changes no rank).
    """
    x = model.zeros() if params is None else np.asarray(params, float)
    p, J = model.jacobian(commands_mm, tool, x)
    if stations_mm is None:
        A, N, what = J.reshape(-1, model.n_params), _rigid_columns(p), "3D targets, rigid 6-dof gauge"
    else:
        # 001 Eq. (3), r = ‖p_i − P_j‖ − L0_j − ΔL, of every target i from every station j by the one distance
        # residual, the targets as its batch (rows target-major): the model part (M N, k), the nuisance
        # (M N, 4 N): the stations' x, y, z, then the dead paths
        P = np.asarray(stations_mm, float).reshape(-1, 3)
        n, m, k = len(P), len(p), model.n_params
        _, cols, vals = distance_rows_nd(np.broadcast_to(p[:, None], (m, n, 3)), np.broadcast_to(np.arange(k), (n, k)),
                                         tuple(J[:, None, c] for c in range(3)), P[None], np.zeros((1, n)),
                                         np.arange(n), 0.0, k, k + 3 * n)
        A, N = vals[..., :k].reshape(m * n, k), np.zeros((m, n, 4 * n))
        np.put_along_axis(N, np.broadcast_to(cols[:, k:] - k, (m, n, 4)), vals[..., k:], axis=2)
        N = N.reshape(m * n, 4 * n)
        what = f"distances from {len(np.asarray(stations_mm).reshape(-1, 3))} stations, unknown stations and dead paths"
    if held:  # a held motion is no unknown: its zeroed columns add null directions outside every other block
        A = A.copy()
        for g in held:
            A[:, model.slices[g]] = 0.0
    norms = np.linalg.norm(A, axis=0)  # a column no reading depends on stays 0: a null direction
    unit = A / np.where(norms > 1e-12 * norms.max(), norms, np.inf)
    with single_thread_blas():  # medium SVDs: BLAS threads spin-wait on a shared machine (50x slower)
        Un, sn, _ = np.linalg.svd(N / np.linalg.norm(N, axis=0), full_matrices=False)
        Qn = Un[:, sn > 1e-10 * sn[0]]
        proj = unit - Qn @ (Qn.T @ unit)
        if prior is None:
            _, s, Vt = np.linalg.svd(proj, full_matrices=False)
            null = Vt[s <= rtol * s[0]].T
        else:
            null, s = _null_within_prior(proj, prior, norms, model, held, rtol)
    groups = [g for g in list(ALL_MOTIONS) + list(SQUARENESS) + list(model.tool_groups) if g not in held]
    block = {g: np.linalg.norm(null[model.slices[g]], 2) if null.size else 0.0 for g in groups}
    separable = {g: bool(block[g] <= share) for g in groups}
    trades = {}
    for g in groups:
        if separable[g]:
            trades[g] = ()
            continue
        u, sv, wt = np.linalg.svd(null[model.slices[g]], full_matrices=False)
        vecs = null @ wt[sv > share].T
        partners = [h for h in groups if h != g and np.linalg.norm(vecs[model.slices[h]]) > 0.05]
        if np.linalg.norm(unit @ vecs) > 1e-6:
            partners.append("gauge")
        trades[g] = tuple(partners)
    n_held = 0 if prior is not None else sum(model.slices[g].stop - model.slices[g].start for g in held)
    return MotionObservability(separable, trades, null.shape[1] - n_held, s, rtol, what, tuple(held))


def _null_within_prior(proj, prior, norms, model: VolumetricModel, held, rtol: float):
    """(null basis (n, z), singular values) of the projected, column-scaled readings ``proj`` (rows, n) within the
    null space of a prior (rows (r, n) over the model's parameters): the prior determines every direction it
    penalizes (of a smoothness prior: a motion's shape, leaving its trend), so only the directions it leaves
    can be unseen -- exactly, whatever its weight. The basis is orthonormal, in the scaled coordinates of
    ``proj``, 0 on the ``held`` groups (no unknowns)."""
    keep = np.ones(model.n_params, bool)
    for g in held:
        keep[model.slices[g]] = False
    Rp = np.asarray(prior.todense() if hasattr(prior, "todense") else prior, float)
    Rp = (Rp / np.where(norms > 1e-12 * norms.max(), norms, 1.0))[:, keep]  # in the scaled coordinates
    _, sr, Vr = np.linalg.svd(Rp, full_matrices=True)
    rank = int(np.sum(sr > 1e-10 * max(sr.max(initial=0.0), 1e-300)))
    NR = Vr[rank:].T  # (k, f): the directions the prior leaves free
    A = proj[:, keep] @ NR
    scale = np.linalg.norm(A, axis=0)
    unit = A / np.where(scale > 1e-12 * max(scale.max(initial=0.0), 1e-300), scale, np.inf)
    _, s, Vt = np.linalg.svd(unit, full_matrices=False)
    v = Vt[s <= rtol * s[0]].T if s.size else np.zeros((NR.shape[1], 0))
    null = np.zeros((model.n_params, v.shape[1]))
    if v.size:
        d = np.where(np.isfinite(unit).all(axis=0) & (np.abs(unit).sum(axis=0) > 0), 1.0 / np.maximum(scale, 1e-300),
                     1.0)  # unit v = 0 <=> A (D⁻¹ v) = 0; a column no reading sees is a null direction as it is
        back = NR @ (v * d[:, None])
        null[keep] = np.linalg.qr(back)[0]
    return null, s


# --------------------------------------------------------------------------- compensation
#: Working float64 values per table or grid point at the peak (the point, the motions and their chain state,
#: the uncertainty rows, the columns as written): an estimate for :func:`check_table_sizes`.
VALUES_PER_POINT = 64


def _ticks(config: MachineConfig, pitch_mm: float) -> list:
    """Points per axis of a table at ``pitch_mm`` over the travel (end included), as floats (no array)."""
    return [float(np.floor((config.travel_mm[a][1] - config.travel_mm[a][0]) / pitch_mm * (1 - 1e-12))) + 2
            if config.travel_mm[a][1] > config.travel_mm[a][0] else 1.0 for a in AXES]  # inf stays inf


def check_table_sizes(config: MachineConfig, pitch_mm=None, grid_pitch_mm=None, pitch_option: str = "--pitch-mm",
                      grid_option: str = "--grid-pitch-mm") -> None:
    """Refuse, in one line and before any work (:func:`olti_drake.limits.check_allocation`), an axis-table
    pitch or a 3D-grid pitch whose tables would allocate more than the limit."""
    from olti_drake.limits import check_allocation

    if pitch_mm is not None and np.isfinite(pitch_mm) and pitch_mm > 0:
        check_allocation(pitch_option, f"{pitch_mm:g} mm", [float(sum(_ticks(config, pitch_mm))), VALUES_PER_POINT],
                         what="values (axis-table positions x working values per position)",
                         hint=f"use a coarser {pitch_option}")
    if grid_pitch_mm is not None and np.isfinite(grid_pitch_mm) and grid_pitch_mm > 0:
        check_allocation(grid_option, f"{grid_pitch_mm:g} mm", _ticks(config, grid_pitch_mm) + [VALUES_PER_POINT],
                         what="values (grid points x working values per point)", hint=f"use a coarser {grid_option}")


def axis_tables(motions, config: MachineConfig, pitch_mm: float) -> Dict[str, Dict[str, np.ndarray]]:
    """Per axis, the error-motion table at ``pitch_mm`` over its travel (end included).

    Columns: ``position_mm``, then the six motions with units in the names
    (``E_XX_mm, E_YX_mm, E_ZX_mm, E_AX_urad, E_BX_urad, E_CX_urad``).
    """
    if not (np.isfinite(pitch_mm) and pitch_mm > 0):
        raise ValueError(f"pitch_mm must be finite and > 0, got {pitch_mm!r}")
    check_table_sizes(config, pitch_mm, pitch_option="pitch_mm")
    out = {}
    for a in AXES:
        lo, hi = config.travel_mm[a]
        q = np.append(np.arange(lo, hi - 1e-9 * pitch_mm, pitch_mm), hi)
        e = motions.evaluate(a, q)
        cols = {"position_mm": q}
        for r, name in enumerate(motion_names(a)):
            cols[f"{name}_{motion_unit(name)}"] = e[:, r]
        out[a] = cols
    return out


def error_grid(motions, config: MachineConfig, pitch_mm: float, tool: int = 0) -> Dict[str, np.ndarray]:
    """Positioning-error vectors (actual − command − tool offset, mm) on a 3D command grid at ``pitch_mm``.

    Columns ``x_cmd_mm, y_cmd_mm, z_cmd_mm, dx_mm, dy_mm, dz_mm`` (x fastest).
    """
    check_table_sizes(config, grid_pitch_mm=pitch_mm, grid_option="grid pitch_mm")
    ticks = []
    for a in AXES:
        lo, hi = config.travel_mm[a]
        ticks.append(np.append(np.arange(lo, hi - 1e-9 * pitch_mm, pitch_mm), hi))
    Z, Y, X = np.meshgrid(ticks[2], ticks[1], ticks[0], indexing="ij")
    c = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    d = tool_positions(config, motions, c, np.full(len(c), tool)) - c - config.tools[tool]
    return {"x_cmd_mm": c[:, 0], "y_cmd_mm": c[:, 1], "z_cmd_mm": c[:, 2],
            "dx_mm": d[:, 0], "dy_mm": d[:, 1], "dz_mm": d[:, 2]}


def compensate(motions, config: MachineConfig, targets_mm, tool=None, tol_mm: float = 1e-11,
               max_iter: int = 20, lines=None):
    """Commands (M, 3) mm that put the tool point on ``targets_mm`` (M, 3) mm (workpiece frame).

    Newton on the model, vectorized over points: q ← q + (∂p/∂q)⁻¹ (target − p(q)),
    from q = target − tool offset. Returns (commands, residual norms mm). Raises
    ValueError (naming the first point; ``lines``: by its file line) when a command leaves the travel or
    the iteration does not reach ``tol_mm`` in ``max_iter`` steps (refused, not returned).
    """
    target, m = check_points(targets_mm, tool, len(config.tools), "targets", lines)
    q = target - config.tools[m]
    for _ in range(max_iter):
        state = chain_state(config, motions, q, m)
        r = target - state.p
        err = np.linalg.norm(r, axis=1)
        if np.all(err <= tol_mm):
            break
        q = q + np.linalg.solve(command_jacobian(config, motions, state), r[:, :, None])[:, :, 0]
    else:
        bad = int(np.argmax(err))
        raise ValueError(f"compensate: {'point ' + str(bad) if lines is None else _row(bad, lines)} did not "
                         f"converge ({err[bad]:.3g} mm after {max_iter} steps)")
    check_commands(config, q, m, "compensated commands", lines)
    return q, err


# --------------------------------------------------------------------------- files
FORMAT = VOLUMETRIC_RESULT


def motions_document(model: VolumetricModel, params, pitch_mm: float = 10.0) -> dict:
    """The error motions as the ``olti-volumetric/1`` result's model part (formats.md, "Machine tool in 3D").

    Per motion: ISO name, unit, role, the representation (B-spline knots and
    every coefficient, fixed ones as 0, and what is fixed) and its values at
    ``pitch_mm`` over the travel; the squareness (µrad); topology, travel and
    tool offsets (as identified: configured + errors, which are listed too). The identifier adds stations, dead paths, gauge and
    uncertainty.
    """
    cfg = model.config
    motions = model.motions(params)
    tables = axis_tables(motions, cfg, pitch_mm)
    out = {}
    for name in ALL_MOTIONS:
        axis, unit = name[3], motion_unit(name)
        fixed = "0 at both travel ends" if _fixed_ends(name)[1] else "0 at the travel start"
        out[name] = {"axis": axis, "unit": unit, "role": motion_role(name), "fixed": fixed,
                     "coefficients": motions.coefficients[name].tolist(),
                     "positions_mm": tables[axis]["position_mm"].tolist(),
                     "values": tables[axis][f"{name}_{unit}"].tolist()}
    return {**result_header("volumetric"), "conventions": "docs/machine_3d.md",
            "topology": {"tool_chain": list(cfg.tool_chain), "work_chain": list(cfg.work_chain)},
            "travel_mm": {a: list(map(float, cfg.travel_mm[a])) for a in AXES},
            "representation": {"basis": "clamped cubic B-spline", "knot_spacing_mm": cfg.knot_spacing_mm,
                               "knots_mm": {a: cfg.knots(a).tolist() for a in AXES}},
            "tool_offsets_mm": (cfg.tools + motions.tool_offset_errors_mm).tolist(),
            "tool_offsets_identified": model.identify_tool_offsets,
            "tool_offset_errors_mm": motions.tool_offset_errors_mm.tolist(),
            "error_motions": out,
            "squareness_urad": {s: float(v) for s, v in zip(SQUARENESS, motions.squareness_urad)}}


def model_from_document(doc: dict, source: str = "volumetric result"):
    """(VolumetricModel, params) of an ``olti-volumetric/1`` document; one-line ValueError naming the field."""
    def need(cond, field, what):
        if not cond:
            raise ValueError(f"{source}: {field}: {what}")

    need(isinstance(doc, dict) and doc.get("format") == FORMAT, "format", f"expected {FORMAT!r}")
    try:
        topo, rep = doc["topology"], doc["representation"]
        cfg = MachineConfig(tool_chain=tuple(topo["tool_chain"]), work_chain=tuple(topo["work_chain"]),
                            travel_mm={a: tuple(doc["travel_mm"][a]) for a in AXES},
                            knot_spacing_mm=float(rep["knot_spacing_mm"]),
                            tool_offsets_mm=tuple(map(tuple, doc["tool_offsets_mm"])))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{source}: missing or malformed field {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    model = VolumetricModel(cfg, identify_tool_offsets=bool(doc.get("tool_offsets_identified", False)))
    x = model.zeros()   # the identified tool offsets are the configured ones here: errors 0
    for name in ALL_MOTIONS:
        entry = doc.get("error_motions", {}).get(name)
        need(isinstance(entry, dict) and "coefficients" in entry, f"error_motions.{name}", "missing")
        coef = np.asarray(entry["coefficients"], float)
        need(coef.shape == (cfg.n_basis(name[3]),) and np.all(np.isfinite(coef)),
             f"error_motions.{name}.coefficients", f"expected {cfg.n_basis(name[3])} finite values")
        fixed = np.setdiff1d(np.arange(len(coef)), model.free[name])
        need(np.all(coef[fixed] == 0), f"error_motions.{name}.coefficients", f"must be 0 at {fixed.tolist()}")
        x[model.slices[name]] = coef[model.free[name]]
    for s in SQUARENESS:
        v = doc.get("squareness_urad", {}).get(s)
        need(isinstance(v, (int, float)) and np.isfinite(v), f"squareness_urad.{s}", "missing or not finite")
        x[model.slices[s]] = v
    return model, x
