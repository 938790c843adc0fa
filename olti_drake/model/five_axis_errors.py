"""The errors of a five-axis machine by their ISO 230-1 / ISO 230-7 names, as one more position model of the one
calibration engine (issue 25, item 2; ``docs/five_axis.md`` states every convention).

* Rotary axis L (A, B or C, turning about x, y or z at zero commands): the **location errors** of its axis
  average line (ISO 230-7): its position in the two radial directions (``E_X0C_mm``, ``E_Y0C_mm`` for C;
  ``E_Y0A_mm``, ``E_Z0A_mm`` for A), its orientation about the two radial directions (``E_A0C_urad``,
  ``E_B0C_urad``; ``E_B0A_urad``, ``E_C0A_urad``), its zero angle (``E_C0C_urad``; ``E_A0A_urad``) and, when
  asked, the axial position (``E_Z0C_mm``); and its six **error motions** as functions of its own commanded
  angle (``E_XC``, ``E_YC`` radial, ``E_ZC`` axial, mm; ``E_AC``, ``E_BC`` tilt, ``E_CC`` angular positioning,
  µrad), piecewise linear on a grid of the command (paper 000's bidirectional map, Eq. 6-9, values at nodes:
  ``E_CC_forward_urad[3]``, ``E_CC_reverse_urad[3]``; one branch, ``forward``, without direction columns).
* Linear axes: the 18 error motions and 3 squareness errors of :mod:`olti_drake.model.volumetric3d` (its
  B-spline parameters ``E_XX[j]`` …, ``E_C0Y_urad`` …), identified (``linear="identify"``), taken from an earlier
  volumetric result (``linear=`` its motions) or absent (``linear=None``).
* Tool offsets: tool m's point in the tool frame (mm); the errors of tools 1, 2, … (``tool1_x_mm``, …) when
  identified, as the 3D machine.

Kinematics: each error is an exact small transform Trans(t)·Rx(a)Ry(b)Rz(c) inserted in the loop
workpiece → tool of :class:`~olti_drake.model.five_axis.FiveAxisMachine`, its components along the machine axes
(base frame at zero commands) of the body carrying it (they move with the axes between it and the base: C's errors
tilt with A). A rotary axis' errors sit in
its carrier (the non-rotating side, ISO 230-7): after the joint's motion in the loop for a table axis, before it
for a head axis; a linear axis' errors follow its motion, Trans(q s + δ) R(ε), as in volumetric3d. Every error
is in the tool-relative-to-workpiece sense. The Jacobian is analytic: ∂p/∂t_i = C e_i, ∂p/∂e_r = C dR_r v (C
the rotation of the loop before the error, v the tool point after it) -- paper 001 Eq. (1)-(3) with the rotary
axes.

Gauge of the error motions (:meth:`FiveAxisPositionModel.gauge_constraints`): per motion, the mean over the grid of the
two branches' average is 0 (the constant is the location error's), and the radial pair and the tilt pair
carry no rotating first harmonic (a constant offset or tilt of the frame downstream). Smoothness:
:meth:`FiveAxisPositionModel.roughness`, 000's map prior (:meth:`olti_drake.model.errormap.ErrorMap.roughness`).
Units: mm, deg (commands), µrad.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.model.five_axis import DEG, LINEAR, ROTARY, AxisLink, FiveAxisMachine, motion
from olti_drake.model.serial import Gauge, GaugeConstraint, JointMap
from olti_drake.model.volumetric3d import (ALL_MOTIONS, IMPLAUSIBLE_MM, IMPLAUSIBLE_URAD, SQUARENESS, MachineConfig,
                                           MotionJacobian, VolumetricModel, _rotations, axis_directions, motion_names,
                                           motion_roughness, motions_document, roughness_lever_mm)

COMPONENTS = ("X", "Y", "Z", "A", "B", "C")
URAD = 1e-6
BRANCHES = ("forward", "reverse")


def unit(component: str) -> str:
    """'mm' for a translation component (X, Y, Z), 'urad' for a rotation (A, B, C)."""
    return "mm" if component in LINEAR else "urad"


def radial(letter: str) -> Tuple[str, str]:
    """The two linear letters across rotary axis ``letter`` (u, v with u × v along it): C → (X, Y), A → (Y, Z),
    B → (Z, X)."""
    i = ROTARY.index(letter)
    return LINEAR[(i + 1) % 3], LINEAR[(i + 2) % 3]


def location_components(letter: str, axial: bool = False) -> Tuple[str, ...]:
    """The components of rotary axis ``letter``'s location errors (ISO 230-7): the radial positions, the tilts,
    the zero angle (and the axial position when ``axial``)."""
    u, v = radial(letter)
    i = ROTARY.index(letter)
    tilts = (ROTARY[(i + 1) % 3], ROTARY[(i + 2) % 3])
    return (u, v) + ((LINEAR[i],) if axial else ()) + tilts + (letter,)


def location_names(letter: str, axial: bool = False) -> Tuple[str, ...]:
    """``E_X0C_mm``, ``E_Y0C_mm``, (``E_Z0C_mm``,) ``E_A0C_urad``, ``E_B0C_urad``, ``E_C0C_urad`` for C."""
    return tuple(f"E_{c}0{letter}_{unit(c)}" for c in location_components(letter, axial))


def node_grid(lo_deg: float, hi_deg: float, pitch_deg: float) -> np.ndarray:
    """Nodes from ``lo_deg`` to ``hi_deg`` every ``pitch_deg`` (deg), the end included (±inf travel: ±180)."""
    lo = lo_deg if np.isfinite(lo_deg) else -180.0
    hi = hi_deg if np.isfinite(hi_deg) else 180.0
    if not (np.isfinite(pitch_deg) and pitch_deg > 0):
        raise InputError(f"pitch_deg: must be finite and > 0, got {pitch_deg!r}")
    return np.append(np.arange(lo, hi - 1e-9 * pitch_deg, pitch_deg), hi)


def linear_config(machine: FiveAxisMachine, knot_spacing_mm: float = 50.0) -> MachineConfig:
    """The 3-axis :class:`~olti_drake.model.volumetric3d.MachineConfig` of the machine's linear axes: topology
    (table-side and head-side axes, base outward) and travel from the file."""
    sides = {s: [e.letter for e in machine.loop if isinstance(e, AxisLink) and e.kind == "prismatic" and e.side == s]
             for s in ("table", "head")}
    travel = {a: (float(machine.lower[machine.axes.index(a)]), float(machine.upper[machine.axes.index(a)]))
              for a in LINEAR}
    return MachineConfig(tool_chain=tuple(sides["head"]), work_chain=tuple(reversed(sides["table"])),
                         travel_mm=travel, knot_spacing_mm=knot_spacing_mm, tool_offsets_mm=((0.0, 0.0, 0.0),))


class _Still:
    """Linear axes without errors (squareness 0): the loop's linear error links in place, all zero."""

    squareness_urad = np.zeros(3)

    @staticmethod
    def evaluate(axis, q, derivative=0):
        return np.zeros((len(q), 6))


def carriage_offsets(machine: FiveAxisMachine) -> Dict[str, np.ndarray]:
    """Per linear axis, d (3,) mm in machine axes: where the loop's error frame of the axis sits relative to the
    volumetric model's (:mod:`olti_drake.model.volumetric3d`: the chain's point, the spindle reference point -- the
    tool frame's origin here -- less the downstream commands): minus the fixed offsets between it and the tool frame
    at zero commands. An angular motion ε of the carriage moves a point d away by (R(ε) − I) d."""
    n = len(machine.axes)
    _, state = evaluate_loop(machine, np.zeros((1, n)), lambda letter, q: np.zeros((len(q), 6)), _Still(),
                             np.zeros((1, 3)))
    return {a: -(G @ state.v[j + 1][0]) for a, (j, G, _) in state.errors.items() if a in LINEAR}


def _rotate(e_rad, d) -> np.ndarray:
    """(M, 3) Rx(a) Ry(b) Rz(c) d for e = (a, b, c) rad (M, 3) (:func:`~olti_drake.model.volumetric3d._rotations`'
    convention), without forming the matrices."""
    c, s = np.cos(e_rad), np.sin(e_rad)
    x, y, z = c[:, 2] * d[0] - s[:, 2] * d[1], s[:, 2] * d[0] + c[:, 2] * d[1], np.full(len(e_rad), float(d[2]))
    x, z = c[:, 1] * x + s[:, 1] * z, -s[:, 1] * x + c[:, 1] * z
    y, z = c[:, 0] * y - s[:, 0] * z, s[:, 0] * y + c[:, 0] * z
    return np.column_stack([x, y, z])


class RelocatedMotions:
    """The linear axes' motions of a volumetric result (``evaluate(axis, q)``, ``squareness_urad``; each carriage's
    rotation about the volumetric chain's point) about the loop's error frames instead: the translations plus
    (R(ε) − I) d_axis (:func:`carriage_offsets`), the angles and squareness unchanged -- the same rigid motion of
    every carriage (docs/five_axis.md, "Linear axes from a volumetric result")."""

    def __init__(self, motions, offsets: Dict[str, np.ndarray]):
        self.motions, self.offsets = motions, offsets
        self.squareness_urad = np.asarray(motions.squareness_urad, float)

    def evaluate(self, axis: str, q, derivative: int = 0) -> np.ndarray:
        """(M, 6) the six motions of ``axis`` at q (mm / µrad) about the loop's error frame, or their derivative."""
        e = np.array(self.motions.evaluate(axis, q), float)
        d = self.offsets[axis]
        if not derivative:
            e[:, :3] += _rotate(e[:, 3:] * URAD, d) - d
            return e
        _, dR = _rotations(e[:, 3:] * URAD)
        de = np.array(self.motions.evaluate(axis, q, derivative=1), float)
        de[:, :3] += sum((dR[r] @ d) * de[:, 3 + r, None] * URAD for r in range(3))
        return de


def gauge_patterns(machine: FiveAxisMachine, letter: str, q, constants: bool = True) -> np.ndarray:
    """(len(q), 6, k) what the readings cannot tell from a frame downstream of rotary axis ``letter`` at commands
    q (deg), on its six error components (X, Y, Z, A, B, C): the constants (``constants``; the location errors'),
    then the rotating first harmonics of the radial pair and of the tilt pair (cos and sin part each) -- a constant
    offset or tilt in the rotating frame, seen from the carrier: R(∓σq) d (table axis −, head axis +; σ the
    sign of the axis in the loop)."""
    k, link = machine.link(letter)
    sigma = float(np.sign(machine.base_rotation(k) @ link.axis)[ROTARY.index(letter)])
    psi = (-1.0 if link.side == "table" else 1.0) * sigma * np.asarray(q, float) * DEG
    i = ROTARY.index(letter)
    cols = [np.broadcast_to(np.eye(6)[r], (psi.size, 6)) for r in range(6)] if constants else []
    for a, b in (radial(letter), (ROTARY[(i + 1) % 3], ROTARY[(i + 2) % 3])):
        ia, ib = COMPONENTS.index(a), COMPONENTS.index(b)
        for ca, cb in ((np.cos(psi), np.sin(psi)), (-np.sin(psi), np.cos(psi))):
            col = np.zeros((psi.size, 6))
            col[:, ia], col[:, ib] = ca, cb
            cols.append(col)
    return np.stack(cols, axis=-1)


def linear_layout(model: VolumetricModel, v, uncertainty: bool = False) -> dict:
    """The identified linear axes' values ``v`` (over ``model.parameter_names()``) by ISO name, as an
    ``olti-volumetric/1`` result has them (:func:`~olti_drake.model.volumetric3d.motions_document`): the
    representation (B-spline knots), per motion its axis, unit, role, every ``coefficient`` (the fixed ones 0; mm
    or µrad) and its ``values`` at ``positions_mm`` (every :func:`linear_pitch_mm` of the travel), the
    ``squareness_urad``. With ``uncertainty`` (``v`` standard uncertainties) the coefficients' and squareness'
    only: a value's u needs the covariance (the result writer's)."""
    v = np.asarray(v, float)
    if uncertainty:
        coef = {}
        for name in ALL_MOTIONS:
            full = np.zeros(model.config.n_basis(name[3]))
            full[model.free[name]] = v[model.slices[name]]
            coef[name] = {"coefficients": full.tolist()}
        return {"error_motions": coef, "squareness_urad": {q: float(v[model.slices[q]][0]) for q in SQUARENESS}}
    doc = motions_document(model, v, linear_pitch_mm(model))
    keys = ("axis", "unit", "role", "fixed", "coefficients", "positions_mm", "values")
    return {"representation": doc["representation"], "travel_mm": doc["travel_mm"],
            "error_motions": {n: {k: e[k] for k in keys} for n, e in doc["error_motions"].items()},
            "squareness_urad": doc["squareness_urad"]}


def linear_pitch_mm(model: VolumetricModel) -> float:
    """The spacing (mm) of the stated values of identified linear motions: a quarter of the knot spacing."""
    return model.config.knot_spacing_mm / 4.0


def linear_from_layout(model: VolumetricModel, entry, source: str) -> np.ndarray:
    """The parameter vector of ``model`` from :func:`linear_layout`'s ``entry``; one InputError line naming the
    key when a value is missing, not finite, or a fixed coefficient is not 0."""
    x = model.zeros()
    for name in ALL_MOTIONS:
        coef = (((entry or {}).get("error_motions") or {}).get(name) or {}).get("coefficients")
        n = model.config.n_basis(name[3])
        try:
            coef = np.asarray(coef, float)
        except (TypeError, ValueError):
            coef = np.zeros(0)
        if coef.shape != (n,) or not np.all(np.isfinite(coef)):
            raise InputError(f"{source}: key 'linear.error_motions.{name}.coefficients': expected {n} finite values")
        fixed = np.setdiff1d(np.arange(n), model.free[name])
        if np.any(coef[fixed] != 0):
            raise InputError(f"{source}: key 'linear.error_motions.{name}.coefficients': must be 0 at "
                             f"{fixed.tolist()} (the motion's fixed ends)")
        x[model.slices[name]] = coef[model.free[name]]
    for q in SQUARENESS:
        v = ((entry or {}).get("squareness_urad") or {}).get(q)
        if not isinstance(v, (int, float)) or not np.isfinite(v):
            raise InputError(f"{source}: key 'linear.squareness_urad.{q}': missing or not finite")
        x[model.slices[q]] = float(v)
    return x


# --------------------------------------------------------------------------- the error model
class FiveAxisErrors:
    """The parameters of a five-axis machine's errors, by ISO name, and where each sits in x.

    Args:
        machine: the :class:`FiveAxisMachine`.
        location: the location errors of every rotary axis (5 each, 6 with ``axial``).
        motions: the six error motions of every rotary axis on a grid every ``pitch_deg`` of its travel.
        bidirectional: a forward and a reverse branch per motion (False: one, ``forward``).
        linear: ``"identify"`` (the 21 volumetric parameters of the linear axes on a B-spline every
            ``knot_spacing_mm``), an object with ``evaluate(axis, q)`` and ``squareness_urad`` (known linear
            motions, e.g. an earlier volumetric result's :class:`~olti_drake.model.volumetric3d.SplineMotions`),
            or None (perfect linear axes).
        tool_offsets_mm: tool m's point in the tool frame (mm); ``identify_tool_offsets``: the errors of tools
            1, 2, … are parameters (tool 0 is the reference).
        one_way: {rotary letter: +1 or −1} the axes a campaign approaches from one direction only (an R-test path
            turning C one way): their reverse branches are tied to the forward ones in the gauge
            (:meth:`FiveAxisPositionModel.gauge_constraints`), the backlash no reading separates.
    """

    def __init__(self, machine: FiveAxisMachine, location: bool = True, axial: bool = False, motions: bool = True,
                 pitch_deg: float = 15.0, bidirectional: bool = True, linear=None, knot_spacing_mm: float = 50.0,
                 tool_offsets_mm=((0.0, 0.0, 0.0),), identify_tool_offsets: bool = False, one_way=None):
        if tuple(machine.linear) != tuple(LINEAR) and linear is not None:
            raise InputError(f"machine model {machine.path}: linear-axis errors need the axes X, Y and Z, it has "
                             f"{', '.join(machine.linear) or 'none'}")
        self.machine, self.location, self.axial, self.with_motions = machine, bool(location), bool(axial), bool(motions)
        self.bidirectional = bool(bidirectional)
        self.one_way = ({L: float(v) for L, v in (one_way or {}).items()}  # (no maps: no branches to tie)
                        if self.bidirectional and self.with_motions else {})
        self.tools = np.asarray(tool_offsets_mm, float).reshape(-1, 3)
        if not np.all(np.isfinite(self.tools)):
            raise InputError(f"tool_offsets_mm: not finite: {self.tools.tolist()}")
        names, self.slices = [], {}

        def add(group, group_names):
            self.slices[group] = slice(len(names), len(names) + len(group_names))
            names.extend(group_names)

        self.maps: Dict[Tuple[str, str], JointMap] = {}
        for L in machine.rotary:
            if self.location:
                add(f"location_{L}", location_names(L, axial))
        for L in machine.rotary if self.with_motions else ():
            k = machine.axes.index(L)
            grid = node_grid(machine.lower[k], machine.upper[k], pitch_deg)
            for c in COMPONENTS:
                jm = JointMap.zeros(f"E_{c}{L}", grid, self.bidirectional)
                self.maps[(L, c)] = jm
                add(jm.joint, [f"{jm.joint}_{b}_{unit(c)}[{i}]" for b in BRANCHES[:1 + self.bidirectional]
                               for i in range(grid.size)])
        self.linear_model = None
        self.linear_motions = None if isinstance(linear, str) else linear
        if isinstance(linear, str):
            if linear != "identify":
                raise InputError(f"linear: 'identify', known motions or None, got {linear!r}")
            self.linear_model = VolumetricModel(self.linear_config(knot_spacing_mm))
            add("linear", list(self.linear_model.parameter_names()))
            for name, sl in self.linear_model.slices.items():  # (each motion its own group: separable() holds
                if name in ALL_MOTIONS:                          # the few that trade, not all 21 with them)
                    self.slices[name] = slice(self.slices["linear"].start + sl.start,
                                              self.slices["linear"].start + sl.stop)
        self.tool_groups = tuple(f"tool{m}" for m in range(1, len(self.tools))) if identify_tool_offsets else ()
        for g in self.tool_groups:
            add(g, [f"{g}_{c}_mm" for c in "xyz"])
        self.names: Tuple[str, ...] = tuple(names)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def linear_config(self, knot_spacing_mm: float = 50.0) -> MachineConfig:
        """:func:`linear_config` of the machine."""
        return linear_config(self.machine, knot_spacing_mm)

    def zeros(self) -> np.ndarray:
        return np.zeros(self.n_params)

    def location_values(self, x, letter: str) -> np.ndarray:
        """(6,) the location errors of ``letter`` at x as a (t mm, e µrad) vector in X, Y, Z, A, B, C order."""
        out = np.zeros(6)
        if self.location:
            where = [COMPONENTS.index(c) for c in location_components(letter, self.axial)]
            out[where] = x[self.slices[f"location_{letter}"]]
        return out

    def linear_source(self, x):
        """The linear axes' motions at x (identified, known, or None)."""
        if self.linear_model is not None:
            return self.linear_model.motions(x[self.slices["linear"]])
        return self.linear_motions

    def tool_offsets(self, x) -> np.ndarray:
        """(n_tools, 3) mm: the configured offsets plus the identified errors at x."""
        t = self.tools.copy()
        for m, g in enumerate(self.tool_groups, start=1):
            t[m] = t[m] + x[self.slices[g]]
        return t


# --------------------------------------------------------------------------- the loop with errors
@dataclass
class _Loop:
    """One pass over the loop with its errors: per link, the rotation before it (C) and the tool point after it
    (v), and where each axis' error and motion links are."""

    p: np.ndarray
    C: list
    v: list
    errors: Dict[str, Tuple[int, np.ndarray, tuple]] = field(default_factory=dict)  # letter -> (link, G, dR)
    motions: Dict[str, Tuple[int, np.ndarray, float]] = field(default_factory=dict)  # letter -> (link, G, sign)
    axes: Dict[str, Tuple[int, np.ndarray]] = field(default_factory=dict)  # letter -> (its motion's link, unit s)


def _error_link(G, values):
    """(R, o, dR) of an error Trans(t) Rx(a)Ry(b)Rz(c) with base components ``values`` (M, 6) (mm, µrad) in a
    frame whose base orientation is G: o = Gᵀ t, R = Gᵀ R(e) G."""
    R, dR = _rotations(values[:, 3:] * URAD)
    return (G.T @ R @ G, values[:, :3] @ G, dR)


def evaluate_loop(machine: FiveAxisMachine, commands, rotary_errors, linear, tool_points, frame: str = "workpiece"):
    """The tool points (M, 3) mm of commands (M, n_axes) with errors, and the pass (:class:`_Loop`).

    ``rotary_errors(letter, q)`` -> (M, 6) the rotary axis' total error (location + motion; X, Y, Z mm, A, B, C
    µrad, machine axes); ``linear``: motions with ``evaluate(axis, q)`` (M, 6) and ``squareness_urad``, or None;
    ``tool_points`` (M, 3) the tool point in the tool frame, mm; ``frame``: 'workpiece' or 'base' (the loop from
    the base: table-side errors do not move the tool in the base frame)."""
    M = len(commands)
    start = {"workpiece": 0, "base": machine.base_index}[frame]
    zero = machine.zero_rotations()
    dirs = axis_directions(linear.squareness_urad) if linear is not None else None
    links, errors, motions, axes = [], {}, {}, {}
    for k in range(start, len(machine.loop)):
        e = machine.loop[k]
        if isinstance(e, np.ndarray):
            links.append((np.broadcast_to(e[:3, :3], (M, 3, 3)), np.broadcast_to(e[:3, 3], (M, 3))))
            continue
        G = zero[machine.base_index].T @ zero[k]  # base orientation of this point at zero commands
        q = commands[:, e.column]
        if e.kind == "prismatic":
            sign = float(np.sign(G @ e.axis)[LINEAR.index(e.letter)])
            if linear is None:
                axes[e.letter] = (len(links), e.axis)
                links.append(motion(e, q))
                continue
            s = sign * (G.T @ dirs[e.letter][0])  # the reference straight line, squareness included
            motions[e.letter], axes[e.letter] = (len(links), G, sign), (len(links), s)
            links.append((np.broadcast_to(np.eye(3), (M, 3, 3)), q[:, None] * s))
            R, o, dR = _error_link(G, linear.evaluate(e.letter, q))
            errors[e.letter] = (len(links), G, dR)
            links.append((R, o))
            continue
        R, o, dR = _error_link(G, rotary_errors(e.letter, q))
        Rm, om = motion(e, q)
        if e.side == "table":  # the carrier is after the motion (workpiece → base)
            axes[e.letter] = (len(links), e.axis)
            links.append((Rm, om))
        errors[e.letter] = (len(links), G, dR)
        links.append((R, o))
        if e.side == "head":
            axes[e.letter] = (len(links), e.axis)
            links.append((Rm, om))
    v = [None] * (len(links) + 1)
    v[-1] = tool_points
    for j in range(len(links) - 1, -1, -1):
        R, o = links[j]
        v[j] = o + np.einsum("mij,mj->mi", R, v[j + 1])
    C, acc = [], np.broadcast_to(np.eye(3), (M, 3, 3))
    for R, _ in links:
        C.append(acc)
        acc = acc @ R
    C.append(acc)
    return v[0], _Loop(v[0], C, v, errors, motions, axes)


def _sensitivities(state: _Loop, letter: str, direction=None):
    """∂p/∂(t_x, t_y, t_z, e_a, e_b, e_c) (M, 3, 6) of the error link of ``letter`` (mm/mm, mm/µrad), or None
    when the loop does not pass it (a table axis seen from the base). ``direction`` (M, 3) a unit vector of the
    tool frame seen in the loop's first frame: its derivatives instead (a direction: no translation part)."""
    if letter not in state.errors:
        return None
    j, G, dR = state.errors[letter]
    CG = state.C[j] @ G.T
    out = np.empty(CG.shape[:2] + (6,))
    out[:, :, :3] = CG if direction is None else 0.0
    after = state.v[j + 1] if direction is None else np.einsum("mji,mj->mi", state.C[j + 1], direction)
    for r in range(3):
        out[:, :, 3 + r] = np.einsum("mij,mj->mi", CG @ dR[r] @ G, after) * URAD
    return out


class FiveAxisPositionModel:
    """The tool points of a five-axis campaign on :class:`FiveAxisErrors`, a position model of the one engine
    (:mod:`olti_drake.model.position_model`; read by
    :class:`~olti_drake.model.measurements.StationDistanceMeasurement`, 001 Eq. (3)).

    Point i is the tool point of tool ``tool[i]`` at ``commands[i]`` (columns ``machine.axes``, mm / deg) with
    the approach directions ``directions[i]`` (±1 per rotary axis, columns ``machine.rotary``; needed when the
    error model is bidirectional), in the workpiece frame (``frame="workpiece"``: stations riding on the table,
    R-test, CNC TCP) or the base frame (``"base"``: stations on the bed). x: ``error_model.names`` (mm, µrad) less
    those ``held`` at 0 (a location error's name, an error motion ``E_XC`` with all its nodes, ``linear``,
    ``tool<m>``: what the campaign does not separate, :func:`separable`); :meth:`theta` the full vector. Start 0
    (the nominal machine of the file). The Jacobian is analytic (:class:`MotionJacobian`, row-compressed, its
    columns fixed by the commands).
    """

    dim = 3

    def __init__(self, machine: FiveAxisMachine, error_model: FiveAxisErrors, commands, directions=None, tool=None,
                 frame: str = "workpiece", held=()):
        if error_model.machine is not machine:
            raise InputError("error_model: built for another machine")
        if frame not in ("workpiece", "base"):
            raise InputError(f"frame: 'workpiece' or 'base', got {frame!r}")
        self.machine, self.errors, self.frame = machine, error_model, frame
        self.commands = machine.check_commands(commands)
        M = len(self.commands)
        self.tool = np.zeros(M, int) if tool is None else np.broadcast_to(np.asarray(tool), (M,)).astype(int)
        if np.any((self.tool < 0) | (self.tool >= len(error_model.tools))):
            raise InputError(f"tool: indices must be in 0..{len(error_model.tools) - 1}, got "
                             f"{np.unique(self.tool)[:5].tolist()}")
        self.directions = _check_directions(directions, M, machine.rotary, error_model.bidirectional and
                                            bool(error_model.maps))
        self.held = tuple(held)
        self.free_cols = _free_columns(error_model, self.held)
        self.names = tuple(error_model.names[i] for i in self.free_cols)
        self._interp = {L: error_model.maps[(L, "X")].interpolation(self.commands[:, machine.axes.index(L)],
                                                                      self._dir(L))
                        for L in machine.rotary if (L, "X") in error_model.maps}
        remap = np.full(error_model.n_params + 1, -1)
        remap[self.free_cols] = np.arange(self.free_cols.size)
        cols = remap[self._pattern()]
        self._held_mask = (cols < 0)[:, None, :]  # (a held column: its value 0 on the point's first free column)
        first = np.where(cols >= 0, cols, np.iinfo(int).max).min(axis=1, keepdims=True)
        self._cols = np.where(cols >= 0, cols, np.where(first == np.iinfo(int).max, 0, first))

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_points(self) -> int:
        return len(self.commands)

    def _dir(self, letter):
        return None if self.directions is None else self.directions[:, self.machine.rotary.index(letter)]

    def start_vector(self) -> np.ndarray:
        return np.zeros(self.n_params)

    def theta(self, x) -> np.ndarray:
        """The error model's full vector (held parameters 0) from x (its first :attr:`n_params` values)."""
        t = self.errors.zeros()
        t[self.free_cols] = np.asarray(x, float)[:self.n_params]
        return t

    # ------------------------------------------------------------------ kinematics
    def _rotary(self, x):
        em = self.errors

        def errors(letter, q):
            out = np.broadcast_to(em.location_values(x, letter), (len(q), 6)).copy()
            if letter in self._interp:
                cols, w = self._interp[letter]
                for r, c in enumerate(COMPONENTS):
                    out[:, r] += np.sum(w * x[em.slices[f"E_{c}{letter}"]][cols], axis=1)
            return out
        return errors

    def _state(self, x):
        """The loop at the full vector x."""
        t = self.errors.tool_offsets(x)[self.tool]
        return evaluate_loop(self.machine, self.commands, self._rotary(x), self.errors.linear_source(x), t,
                             self.frame)

    def positions(self, x=None) -> np.ndarray:
        """(N, 3) mm tool points at x (default the start)."""
        return self._state(self.theta(self.start_vector() if x is None else x))[0]

    def _pattern(self) -> np.ndarray:
        """(N, m) the columns of every point: location errors, the two map nodes its commands reach per motion,
        the linear parameters, its tool's offset errors (tool 0's rows: tool 1's columns, value 0)."""
        em, N = self.errors, self.n_points
        blocks = [np.broadcast_to(np.arange(em.slices[f"location_{L}"].start, em.slices[f"location_{L}"].stop),
                                  (N, em.slices[f"location_{L}"].stop - em.slices[f"location_{L}"].start))
                  for L in self.machine.rotary if em.location]
        for L, (cols, _) in self._interp.items():
            blocks += [em.slices[f"E_{c}{L}"].start + cols for c in COMPONENTS]
        if em.linear_model is not None:
            s = em.slices["linear"]
            blocks.append(np.broadcast_to(np.arange(s.start, s.stop), (N, s.stop - s.start)))
        if em.tool_groups:
            first = np.maximum(self.tool, 1)
            blocks.append(em.slices["tool1"].start + 3 * (first - 1)[:, None] + np.arange(3))
        if not blocks:
            return np.zeros((N, 1), int)
        return np.hstack(blocks).astype(int)

    def _compressed(self, x):
        """Tool points (N, 3) and the Jacobian values (N, 3, m) on :attr:`_cols` at the full vector x."""
        em = self.errors
        p, state = self._state(x)
        sens = {L: _sensitivities(state, L) for L in self.machine.rotary}
        sens = {L: np.zeros((self.n_points, 3, 6)) if S is None else S for L, S in sens.items()}
        vals = [sens[L][:, :, [COMPONENTS.index(c) for c in location_components(L, em.axial)]]
                for L in self.machine.rotary if em.location]  # (the order of _pattern)
        for L, (_, w) in self._interp.items():
            vals += [sens[L][:, :, r, None] * w[:, None, :] for r in range(6)]
        if em.linear_model is not None:
            vals.append(self._linear_columns(state, x))
        if em.tool_groups:
            vals.append(state.C[-1] * (self.tool > 0)[:, None, None])
        if not vals:
            return p, np.zeros((self.n_points, 3, 1))
        return p, np.where(self._held_mask, 0.0, np.concatenate(vals, axis=2))

    def _linear_columns(self, state: _Loop, x) -> np.ndarray:
        """(N, 3, n_linear): the B-spline coefficients (sensitivity × basis) and the squareness
        (C q sign Gᵀ ds_k/dθ, mm/µrad) of the volumetric parameters."""
        vm = self.errors.linear_model
        motions = vm.motions(x[self.errors.slices["linear"]])
        out = np.zeros((self.n_points, 3, vm.n_params))
        for a in LINEAR:
            S = _sensitivities(state, a)
            if S is None:
                continue
            q = self.commands[:, self.machine.axes.index(a)]
            basis = motions.basis(a, q)
            for r, name in enumerate(motion_names(a)):
                out[:, :, vm.slices[name]] = S[:, :, r, None] * basis[:, None, vm.free[name]]
        dirs = axis_directions(motions.squareness_urad)
        for r, (name, a) in enumerate(zip(SQUARENESS, ("Y", "Z", "Z"))):
            if a not in state.motions:
                continue
            j, G, sign = state.motions[a]
            q = self.commands[:, self.machine.axes.index(a)]
            ds = sign * (G.T @ dirs[a][1][r]) * URAD
            out[:, :, vm.slices[name].start] = np.einsum("mij,j->mi", state.C[j], ds) * q[:, None]
        return out

    def jacobian(self, x=None):
        """(N, 3) tool points and their :class:`MotionJacobian` over :attr:`names` (analytic)."""
        p, vals = self._compressed(self.theta(self.start_vector() if x is None else x))
        return p, MotionJacobian(self._cols, vals, self.n_params)

    def command_jacobian(self, x=None):
        """The tool pose and its derivatives in the commands at x (default the start), analytic: tool points p
        (N, 3) mm, tool directions d (N, 3) (the tool frame's z axis, unit), ∂p/∂q and ∂d/∂q (N, 3, n_axes) per mm
        and per deg (columns ``machine.axes``). Each axis contributes its motion (C s for a prismatic axis, C (s ×
        v) and (C s) × d for a revolute one, per deg) and the slope of its errors in its own command through its
        error link's sensitivities (an error map's slope is its segment's; the linear motions' derivative)."""
        theta = self.theta(self.start_vector() if x is None else x)
        p, state = self._state(theta)
        d = state.C[-1][:, :, 2]
        Jp, Jd = np.zeros(p.shape + (len(self.machine.axes),)), np.zeros(p.shape + (len(self.machine.axes),))
        slopes = self._error_slopes(theta, state)
        for letter, (j, s) in state.axes.items():
            k = self.machine.axes.index(letter)
            Cs = state.C[j] @ s
            if letter in LINEAR:
                Jp[:, :, k] = Cs
            else:
                Jp[:, :, k] = np.einsum("mij,mj->mi", state.C[j], np.cross(s, state.v[j])) * DEG
                Jd[:, :, k] = np.cross(Cs, d) * DEG
            if letter in slopes:
                Jp[:, :, k] += np.einsum("mir,mr->mi", _sensitivities(state, letter), slopes[letter])
                Jd[:, :, k] += np.einsum("mir,mr->mi", _sensitivities(state, letter, d), slopes[letter])
        return p, d, Jp, Jd

    def _error_slopes(self, theta, state: _Loop) -> Dict[str, np.ndarray]:
        """Per axis whose errors vary with its command: their derivative (N, 6) in it (mm and µrad per deg or per
        mm): a map's slope on the segment holding the command, the linear motions' first derivative."""
        em, out = self.errors, {}
        for L, (cols, _) in self._interp.items():
            g = em.maps[(L, "X")].emap.grid_deg
            if g.size < 2:
                continue
            i = cols[:, 0] % g.size  # (the node within its branch)
            dw = np.array([-1.0, 1.0]) / (g[i + 1] - g[i])[:, None]
            out[L] = np.column_stack([np.sum(dw * theta[em.slices[f"E_{c}{L}"]][cols], axis=1) for c in COMPONENTS])
        linear = em.linear_source(theta)
        for a in state.motions if linear is not None else ():
            out[a] = linear.evaluate(a, self.commands[:, self.machine.axes.index(a)], derivative=1)
        return out

    def rows(self, X, points):
        """Batched for T parameter vectors X (T, n ≥ n_params): p (T, K, 3) mm, cols (K, m), dp per coordinate
        (T, K, m) at the points ``points`` (K,) (for :func:`~olti_drake.model.measurements.distance_rows_nd`)."""
        X = np.atleast_2d(np.asarray(X, float))
        out = [self._compressed(self.theta(x)) for x in X]
        p = np.stack([o[0] for o in out])[:, points]
        vals = np.stack([o[1] for o in out])[:, points]
        return p, self._cols[points], tuple(vals[:, :, c] for c in range(3))

    # ------------------------------------------------------------------ priors and gauge
    def roughness(self, linear: bool = True) -> Optional[sp.csr_matrix]:
        """000's map smoothness rows (:meth:`JointMap.roughness`: each branch and the backlash) of every error
        motion over x, and (``linear``) the identified linear axes'
        (:func:`~olti_drake.model.volumetric3d.motion_roughness`); None without motions. An angular motion (µrad)
        counts at the tool point it moves: times :meth:`roughness_lever_mm` of its rotary axis · 10⁻⁶ (mm per
        µrad; the linear axes' angular motions at the linear travel's lever), so that one weight serves mm and
        µrad alike (as the 3-axis machine's prior)."""
        blocks = self._roughness_blocks(linear)
        return blocks[0] if blocks is not None else None

    def roughness_groups(self, linear: bool = True) -> Optional[Tuple[str, ...]]:
        """The group of each :meth:`roughness` row: the error motion it smooths (``E_XA``, …; ``linear axes`` for
        the identified linear axes' rows) -- each its own smoothness weight when the weight is chosen from the
        data (:func:`~olti_drake.estimation.smoothing.group_weights`: a rough E_CC beside smooth radial motions)."""
        blocks = self._roughness_blocks(linear)
        return blocks[1] if blocks is not None else None

    def _roughness_blocks(self, linear: bool):
        """(R over the free columns, the group label of each row), or None without motions."""
        em = self.errors
        blocks, labels = [], []
        levers = {L: self.roughness_lever_mm(L) * 1e-6 for L in self.machine.rotary}

        def add(label, R, s):
            blocks.append(sp.hstack([sp.csr_matrix((R.shape[0], s.start)), R,
                                     sp.csr_matrix((R.shape[0], em.n_params - s.stop))]))
            labels.extend([label] * R.shape[0])

        if linear and em.linear_model is not None:  # (the 3-axis machine's prior, same lever)
            add("linear axes", motion_roughness(em.linear_model, self.roughness_lever_mm()), em.slices["linear"])
        for (L, c), jm in em.maps.items():
            R = jm.roughness()
            if R.shape[0]:
                add(jm.joint, R * levers[L] if unit(c) == "urad" else R, em.slices[jm.joint])
        if not blocks:
            return None
        R = sp.vstack(blocks, format="csr")[:, self.free_cols]
        keep = np.flatnonzero(R.getnnz(axis=1))  # (rows on held motions only: none)
        return R[keep], tuple(np.asarray(labels, dtype=object)[keep])

    def roughness_lever_mm(self, letter: Optional[str] = None) -> float:
        """The lever (mm) at which an angular error motion's roughness counts as the tool point's (an angle
        of ε µrad moves a point that far by ε·lever·10⁻⁶ mm).

        ``letter`` a rotary axis: the largest distance of a nominal tool point from the axis' error link
        (|∂p/∂e| / 10⁻⁶ over its three angles, :func:`_sensitivities`), as the linear axes' lever is the
        largest distance from the centre of their travel. Not the span of the points: that is nil on one
        R-test ball or nest while the ball's lever about the axis is not (the span gave 2·10⁻⁶ mm there,
        so no smoothness prior on the angular motions at all). None (the linear axes' angular motions),
        and an axis that moves no point: half the travel diagonal of the linear axes' commands, the
        3-axis machine's lever (:func:`~olti_drake.model.volumetric3d.roughness_lever_mm`)."""
        if letter is not None:
            S = _sensitivities(self._state(self.theta(self.start_vector()))[1], letter)
            # (a point r from the error link's origin moves by |e × r|: Σ over the three angles of |∂p/∂e|² = 2 r²)
            lever = 0.0 if S is None else float(np.sqrt(np.max(np.sum(S[:, :, 3:] ** 2, axis=(1, 2))) / 2)) / URAD
            if lever > 0.0:
                return lever
        m = self.machine
        return roughness_lever_mm(self.commands[:, [m.axes.index(a) for a in m.axes if a not in m.rotary]])

    def gauge_constraints(self, full_turns: bool = True) -> Tuple[GaugeConstraint, ...]:
        """The error motions' gauge, A x = 0 (module docstring; :func:`gauge_patterns`): per motion the grid mean
        of the branches' average (when the location errors are parameters: they hold the constant), and per
        radial pair and tilt pair the two components of the rotating first harmonic (a constant offset or tilt of
        the frame downstream: the workpiece frame, the next axis' location, tool 0's offset). Trapezoid weights
        over the grid. Then the one-way ties and (``full_turns``) the full-turn ties (:meth:`_full_turn_ties`)."""
        em, out = self.errors, []
        for L in self.machine.rotary:
            if (L, "X") not in em.maps:
                continue
            g = em.maps[(L, "X")].emap.grid_deg
            w = np.zeros(g.size)
            w[:-1] += np.diff(g) / 2
            w[1:] += np.diff(g) / 2
            w /= w.sum()
            branches = 2 if em.bidirectional else 1
            patterns = gauge_patterns(self.machine, L, g, em.location)
            what = ([f"E_{c}{L} has mean 0 over its grid (its constant is the location error)" for c in COMPONENTS]
                    if em.location else []) + [f"{kind} motions of {L}: no rotating first harmonic ({part} part)"
                                               for kind in ("radial", "tilt") for part in ("cos", "sin")]
            for j, text in enumerate(what):
                row = np.zeros(em.n_params)
                for r, c in enumerate(COMPONENTS):
                    row[em.slices[f"E_{c}{L}"]] += np.tile(w * patterns[:, r, j], branches) / branches
                name = f"E_{COMPONENTS[int(np.argmax(np.abs(patterns[0, :, j])))]}{L}"
                if np.any(row[self.free_cols]):  # (a held motion needs no gauge)
                    out.append(GaugeConstraint(name, row[self.free_cols], 0.0, text))
        return tuple(out) + self._one_way_ties() + (self._full_turn_ties() if full_turns else ())

    def full_turns(self) -> Tuple[str, ...]:
        """The rotary axes with maps whose travel is a full turn (−180..180: its two end nodes are one angle)."""
        m = self.machine
        return tuple(L for L in m.rotary if (L, "X") in self.errors.maps
                     and m.upper[m.axes.index(L)] - m.lower[m.axes.index(L)] >= 360.0 - 1e-9)

    def _full_turn_ties(self) -> Tuple[GaugeConstraint, ...]:
        """node[last] = node[0] of every branch of a full-turn axis' motions (:meth:`full_turns`): −180° and +180°
        are one angle, approached the same way; untied, the maps would jump there, the extrapolated ends apart (the
        inverse of a command across the end then finds no pose). A one-way axis ties its forward branch only (its
        reverse is tied to it node by node)."""
        em, out = self.errors, []
        for L in self.full_turns():
            for c in COMPONENTS:
                s, n = em.slices[f"E_{c}{L}"], em.maps[(L, c)].emap.n_nodes
                for b in range(1 if L in em.one_way or not em.bidirectional else 2):
                    row = np.zeros(em.n_params)
                    row[s.start + b * n], row[s.start + b * n + n - 1] = -1.0, 1.0
                    if np.any(row[self.free_cols]):
                        out.append(GaugeConstraint(f"E_{c}{L}", row[self.free_cols], 0.0,
                                                   f"{L} turns a full turn: E_{c}{L} {BRANCHES[b]} at +180 deg = at "
                                                   f"-180 deg"))
        return tuple(out)

    def _one_way_ties(self) -> Tuple[GaugeConstraint, ...]:
        """reverse[i] = forward[i] of every motion node of the axes the campaign approaches one way only
        (:attr:`FiveAxisErrors.one_way`): no reading tells the branches apart there, and an unread branch would
        otherwise take its whole motion out of what the campaign separates (:func:`separable`)."""
        em, out = self.errors, []
        for L, sign in em.one_way.items():
            side = "forward (+)" if sign > 0 else "reverse (-)"
            for c in COMPONENTS:
                if (L, c) not in em.maps:
                    continue
                s, n = em.slices[f"E_{c}{L}"], em.maps[(L, c)].emap.n_nodes
                for i in range(n):
                    row = np.zeros(em.n_params)
                    row[s.start + i], row[s.start + n + i] = 1.0, -1.0
                    if np.any(row[self.free_cols]):
                        out.append(GaugeConstraint(f"E_{c}{L}", row[self.free_cols], 0.0,
                                                   f"{L} approached {side} only: E_{c}{L} reverse = forward "
                                                   f"(its backlash not separable)"))
        return tuple(out)

    def gauge(self, n_total: Optional[int] = None) -> Gauge:
        """:meth:`gauge_constraints` as the engine's :class:`~olti_drake.model.serial.Gauge` over ``n_total``
        parameters (a measurement's own ones after the model's, zero columns)."""
        n = self.n_params if n_total is None else int(n_total)
        cons = tuple(GaugeConstraint(c.name, np.concatenate([c.row, np.zeros(n - self.n_params)]), c.value, c.text)
                     for c in self.gauge_constraints())
        one_way = "".join(f"; {L} approached one way only: its reverse branches = the forward ones"
                          for L in self.errors.one_way)
        turns = "".join(f"; {L} turns a full turn: its maps equal at -180 and +180 deg" for L in self.full_turns())
        return Gauge(cons, 0, "error motions: mean 0 and no rotating first harmonic per rotary axis "
                              f"(docs/five_axis.md){one_way}{turns}", n)

    # ------------------------------------------------------------------ results
    def layout(self, v, uncertainty: bool = False) -> dict:
        """x-shaped ``v`` (values or uncertainties) in the ``olti-machine5/1`` keys: ``location_errors`` by name,
        ``error_motions`` per ISO name (axis, unit, ``grid_deg``, ``forward``, ``reverse`` when bidirectional),
        ``linear`` (identified linear axes, :func:`linear_layout`), ``tool_offset_errors_mm``."""
        em, v = self.errors, self.theta(v)
        out = {"location_errors": {}, "error_motions": {}}
        for L in self.machine.rotary if em.location else ():
            s = em.slices[f"location_{L}"]
            out["location_errors"].update({n: float(x) for n, x in zip(em.names[s], v[s])})
        for (L, c), jm in em.maps.items():
            vals = v[em.slices[jm.joint]]
            n = jm.emap.n_nodes
            entry = {"axis": L, "unit": unit(c), "grid_deg": jm.emap.grid_deg.tolist(), "forward": vals[:n].tolist()}
            if em.bidirectional:
                entry["reverse"] = vals[n:].tolist()
            out["error_motions"][jm.joint] = entry
        if em.linear_model is not None:
            out["linear"] = linear_layout(em.linear_model, v[em.slices["linear"]], uncertainty)
        out["tool_offset_errors_mm"] = [v[em.slices[g]].tolist() for g in em.tool_groups]
        return out

    def station_reference(self):
        """(centre, span, its name) for a station's plausibility: the nominal tool points' centroid and diagonal."""
        p = self.positions()
        return p.mean(axis=0), float(np.linalg.norm(np.ptp(p, axis=0))), "the tool points' diagonal"

    #: A location error beyond this (mm, µrad) is a wrong model or a unit slip, not a machine's error.
    LOCATION_BOUND_MM, LOCATION_BOUND_URAD = 10.0, 2e4

    def implausible(self, x) -> list:
        """Values no machine has, one phrase each: a location error over 10 mm / 20 000 µrad, an error-motion node
        over 1 mm / 10 000 µrad, a linear axis' motion over those anywhere on its travel
        (:data:`~olti_drake.model.volumetric3d.IMPLAUSIBLE_MM`, ``IMPLAUSIBLE_URAD``: a unit slip, a wrong model)."""
        em, x = self.errors, self.theta(x)
        out = []
        for L in self.machine.rotary if em.location else ():
            s = em.slices[f"location_{L}"]
            for name, v in zip(em.names[s], x[s]):
                limit = self.LOCATION_BOUND_MM if name.endswith("_mm") else self.LOCATION_BOUND_URAD
                if abs(v) > limit:
                    out.append(f"{name} = {v:.6g} (over {limit:g})")
        for (L, c), jm in em.maps.items():
            v = np.abs(x[em.slices[jm.joint]]).max()
            limit = IMPLAUSIBLE_MM if unit(c) == "mm" else IMPLAUSIBLE_URAD
            if v > limit:
                out.append(f"{jm.joint} reaches {v:.6g} {unit(c)} at a node (over {limit:g})")
        motions = em.linear_source(x) if em.linear_model is not None else None
        for a in LINEAR if motions is not None else ():
            k = self.machine.axes.index(a)
            v = np.abs(motions.evaluate(a, np.linspace(self.machine.lower[k], self.machine.upper[k], 101))).max(axis=0)
            for r, name in enumerate(motion_names(a)):
                limit = IMPLAUSIBLE_MM if r < 3 else IMPLAUSIBLE_URAD
                if v[r] > limit:
                    out.append(f"{name} reaches {v[r]:.6g} {unit(COMPONENTS[r])} (over {limit:g})")
        return out


def _free_columns(em: FiveAxisErrors, held) -> np.ndarray:
    """Indices of the error model's parameters not ``held`` (names or groups); unknown names refused."""
    mask = np.ones(em.n_params, bool)
    for h in held:
        if h in em.names:
            mask[em.names.index(h)] = False
        elif h in em.slices and not h.startswith("location_"):
            mask[em.slices[h]] = False
        else:
            raise InputError(f"held: {h!r} is no parameter or group of this model (a location error such as "
                             f"E_X0C_mm, an error motion such as E_XC, linear, tool1)")
    return np.flatnonzero(mask)


def _check_directions(directions, M: int, rotary, needed: bool):
    """(M, n_rotary) ±1 or None; one-line InputError otherwise."""
    if directions is None:
        if needed:
            raise InputError("directions: the error model is bidirectional; give the approach directions "
                             f"({', '.join('dir_' + a.lower() for a in rotary)}) or build it with bidirectional=False")
        return None
    d = np.asarray(directions, float).reshape(M, -1) if np.size(directions) == M * len(rotary) else None
    if d is None or not np.all(np.isin(d, (-1.0, 1.0))):
        raise InputError(f"directions: expected (M, {len(rotary)}) values ±1 for {', '.join(rotary)}")
    return d


def representation_bound(em: FiveAxisErrors, truth, samples: int = 721) -> Dict[Tuple[str, str], float]:
    """Per error motion and branch, ``(E_XC, "forward")`` -> b (mm or µrad): how far a continuous truth (any
    object with ``motion_values(L, q, direction)`` (M, 6), e.g. :class:`~olti_drake.model.five_axis_truth.
    FiveAxisTruth`) lies from its representation on ``em``'s grid -- the truth sampled at the nodes and
    interpolated as the model does (piecewise linear, paper 000 Eq. (7)-(9)), the largest deviation over the
    travel (``samples`` commands). A map value is then compared with the truth within 3 u + b."""
    out = {}
    for (L, c), jm in em.maps.items():
        g = jm.emap.grid_deg
        q = np.linspace(g[0], g[-1], samples)
        r = COMPONENTS.index(c)
        for b, sign in zip(BRANCHES[:1 + em.bidirectional], (1.0, -1.0)):
            nodes = truth.motion_values(L, g, sign)[:, r]
            out[(jm.joint, b)] = float(np.max(np.abs(np.interp(q, g, nodes) - truth.motion_values(L, q, sign)[:, r])))
    return out


# --------------------------------------------------------------------------- what a campaign separates
@dataclass(frozen=True)
class Separability:
    """Per parameter group (a location error by name, an error motion ``E_XC`` (its nodes), ``linear``,
    ``tool<m>``): separable or not, and why not; :attr:`dropped` in the order they were dropped (hold them:
    ``FiveAxisPositionModel(..., held=dropped)``)."""

    separable: Dict[str, bool]
    reasons: Dict[str, str]
    dropped: Tuple[str, ...]
    measurement: str

    def describe(self) -> str:
        if not self.dropped:
            return f"all {len(self.separable)} error groups separable ({self.measurement})"
        return "\n".join(f"{g}: dropped, {self.reasons[g]}" for g in self.dropped)


#: Dropped first when the null space holds them: a rotary axis' zero angle is where its reference mark is, the
#: location error a measurement relative to the workpiece sees least directly (its tilt partners are kept).
PREFER_DROPPING = ("E_A0A_urad", "E_B0B_urad", "E_C0C_urad")


def separable(model: FiveAxisPositionModel, stations_mm=None, rtol: float = 1e-8, share: float = 1e-3,
              prefer: Tuple[str, ...] = PREFER_DROPPING, jacobian=None, prior=None) -> Separability:
    """Which location errors and error motions a campaign separates, and the fewest to drop so that the rest is.

    The model's Jacobian at its commands with the measurement's own unknowns (``stations_mm`` (N, 3): distances
    from every station, unknown stations and dead paths, 001 Eq. (3); None: 3D points in an unknown rigid frame),
    the motions' gauge rows appended; columns scaled to unit norm and projected off the nuisance columns (as
    :func:`olti_drake.model.volumetric3d.observability`). While the null space (singular values ≤ ``rtol`` × the
    largest) is not empty, a group holding more than ``share`` of it is dropped -- the first of ``prefer`` among
    them, else the one holding most, a linear axis' motion or squareness before a rotary group --, the reason naming the groups its null directions share ("the measurement's
    gauge" when the nuisance takes part). ``jacobian``: instead, (J, what) of any measurement of the model -- its
    residuals' Jacobian (rows, n_params + its own unknowns: nests, tracker frames, stations), the model's columns
    first -- e.g. a mixed campaign's (:class:`~olti_drake.model.displacements.CombinedMeasurement`). ``prior``:
    the roughness rows of the maps' smoothness prior over the same columns (sparse or dense), appended at 1e-3 of
    the readings' largest column: what the prior determines (a map's shape between and beyond the commanded
    angles) is separable, its trend is not. Before the null space: the angular motions of an axis whose readings
    see it move one point only (:func:`one_point_motions`) are dropped -- the prior would otherwise count their
    trade with the translational ones, node by node, as determined."""
    from olti_drake.threads import single_thread_blas

    J, what = _separability_rows(model, stations_mm) if jacobian is None else (_dense(jacobian[0]), jacobian[1])
    reasons = one_point_motions(model)
    dropped = list(reasons)
    if prior is not None and prior.shape[0]:
        R = _dense(prior)
        scale = 1e-3 * np.linalg.norm(J, axis=0).max() / max(np.linalg.norm(R, axis=0).max(), 1e-300)
        J, what = np.vstack([J, scale * R]), what + ", the maps' smoothness prior"
    A, N, what = _with_ties(model, J, what)
    norms = np.linalg.norm(A, axis=0)
    unit_cols = A / np.where(norms > 1e-12 * norms.max(), norms, np.inf)
    groups = _groups(model)
    linear = set(ALL_MOTIONS) | {f"{q}_urad" for q in SQUARENESS}
    keep = np.ones(model.n_params, bool)
    for g in dropped:
        keep[groups[g]] = False
    with single_thread_blas():  # (medium SVDs: BLAS threads spin on a shared machine)
        Un, sn, _ = np.linalg.svd(N / np.maximum(np.linalg.norm(N, axis=0), 1e-300), full_matrices=False)
        Q = Un[:, sn > 1e-10 * sn[0]]
        proj = unit_cols - Q @ (Q.T @ unit_cols)
        # The SVDs below need only proj's R factor: the same singular values and right vectors of every column
        # subset, min(rows, columns) rows instead of one per reading (2 097 readings, 340 columns: 3.1 -> 0.6 s).
        proj = np.linalg.qr(proj, mode="r")
        while keep.any():
            _, sv, Vt = np.linalg.svd(proj[:, keep], full_matrices=False)
            null = np.zeros((model.n_params, int(np.sum(sv <= rtol * sv[0])) + int(keep.sum()) - sv.size))
            null[keep] = np.hstack([Vt[sv <= rtol * sv[0]].T, np.eye(int(keep.sum()))[:, sv.size:]])
            if not null.shape[1]:
                break
            block = {g: float(np.linalg.norm(null[idx], 2)) for g, idx in groups.items() if g not in dropped}
            inside = [g for g in block if block[g] > share]
            if not inside:
                break
            # (the most-holding group; shares equal to rounding -- one trade seen from both sides -- go to the first
            # in the model's order, not to whichever the readings' row order rounds up)
            # A linear motion before a rotary group: the location errors are a five-axis campaign's first answer.
            pool = [h for h in inside if h in linear] or inside
            top = max(block[h] for h in pool)
            g = next((h for h in prefer if h in inside), next(h for h in pool if block[h] >= top * (1 - 1e-6)))
            dropped.append(g)
            reasons[g] = _reason(g, groups, null, unit_cols, norms, share, dropped)
            keep[groups[g]] = False
    ok = {g: g not in dropped for g in groups}
    return Separability(ok, reasons, tuple(dropped), what)


def _reason(g, groups, null, unit_cols, norms, share, dropped) -> str:
    """Why group g is dropped: no reading depends on it, or what its null directions trade it with."""
    idx = groups[g]
    if not np.any(norms[idx] > 1e-12 * norms.max()):
        return "no reading depends on it"
    _, s, wt = np.linalg.svd(null[idx], full_matrices=False)
    vecs = null @ wt[s > share].T
    partners = [h for h, jdx in groups.items() if h != g and h not in dropped and np.linalg.norm(vecs[jdx]) > 0.05]
    gauge = np.linalg.norm(np.nan_to_num(unit_cols) @ vecs) > 1e-6
    return "trades with " + ", ".join(partners + (["the measurement's gauge"] if gauge or not partners else []))


def _separability_rows(model: FiveAxisPositionModel, stations_mm):
    """(the readings' Jacobian: the model's columns, then the nuisance's; what was measured) of a campaign."""
    from olti_drake.model.measurements import distance_rows_nd
    from olti_drake.model.volumetric3d import _rigid_columns

    n = model.n_params
    p, J = model.jacobian()
    if stations_mm is None:
        A, N, what = J.tocsr().toarray(), _rigid_columns(p), "3D points, rigid 6-dof gauge"
    else:
        P = np.asarray(stations_mm, float).reshape(-1, 3)
        s = len(P)
        pts, sta = np.repeat(np.arange(len(p)), s), np.tile(np.arange(s), len(p))
        X = np.concatenate([model.start_vector(), P.ravel(), np.zeros(s)])[None]
        pp, cols, dp = model.rows(X, pts)
        _, rc, rv = distance_rows_nd(pp, cols, dp, P[None], np.zeros((1, s)), sta, np.zeros(len(pts)), n, n + 3 * s)
        full = np.zeros((len(pts), n + 4 * s))
        np.add.at(full, (np.repeat(np.arange(len(pts)), rc.shape[1]), rc.ravel()), rv[0].ravel())
        A, N, what = full[:, :n], full[:, n:], f"distances from {s} stations, unknown stations and dead paths"
    return np.hstack([A, N]), what


def _dense(M) -> np.ndarray:
    return np.asarray(M.toarray() if hasattr(M, "toarray") else M, float)


def one_point_motions(model, rtol: float = 1e-6) -> Dict[str, str]:
    """{group: reason}: the angular error motions (``E_AC``, ``E_BC``, ``E_CC`` for C) of each rotary axis whose
    readings see it move one point only, to drop.

    An error motion of axis L at angle θ moves a point w of the carried side (in L's carrier frame) by
    t(θ) + ω(θ) × w. Readings of one point per angle -- one R-test nest or ball on a rotary table, w(θ) = R_L(θ) w0,
    or one tool on a head axis -- cannot tell ω from t: t = −ω × w(θ) moves no reading at any angle, and the maps'
    smoothness prior does not see that trade either (it is as smooth as w). The test, per branch of L with at least
    5 distinct points (``model``: a :class:`FiveAxisPositionModel` or one holding several in ``parts``): the rank
    of the sensitivities of its points (:func:`_sensitivities`, 3 rows per point, the best any measurement reads)
    to a constant ω and a t of the first harmonic of θ (unit columns; singular values ≤ ``rtol`` × the largest
    null: exact for a point carried by the axis, ≥ 1e-3 for points spread over the travel). While a branch lacks
    rank, the angular motion holding most of its null directions is dropped: the translational motions then hold
    the tool point's error at the point that was read. Necessary, not sufficient: :func:`separable` follows."""
    em, out = model.errors, {}
    parts = list(getattr(model, "parts", {None: model}).values())
    for L in model.machine.rotary if em.with_motions else ():
        designs = [D for part in parts for D in _one_point_designs(part, L)]
        dropped = []
        while designs:
            shares, lacking = {c: 0.0 for c in ROTARY}, 0
            for D in designs:  # (columns: t's 9, then ω about x, y, z: the angular components A, B, C)
                n_t, angular = D.shape[1] - 3, [c for c in ROTARY if c not in dropped]
                _, sv, Vt = np.linalg.svd(D[:, list(range(n_t)) + [n_t + ROTARY.index(c) for c in angular]],
                                          full_matrices=False)
                null = Vt[sv <= rtol * sv[0]]
                lacking += bool(null.shape[0])
                for j, c in enumerate(angular):
                    shares[c] += float(np.linalg.norm(null[:, n_t + j]))
            candidates = [c for c in ROTARY if c not in dropped and shares[c] > 1e-3]
            if not lacking or not candidates:
                break
            dropped.append(max(candidates, key=shares.get))
            out[f"E_{dropped[-1]}{L}"] = (f"the readings see axis {L} move one point only ({_one_point(model, L)}): "
                                          f"its angular motions trade with its translational ones (t + ω × w at one "
                                          f"w); the translational motions hold the error at that point")
    return {g: why for g, why in out.items() if g in _groups(model)}


def _one_point(model, L: str) -> str:
    side = next(e.side for e in model.machine.loop if isinstance(e, AxisLink) and e.letter == L)
    return "one tool point on the head" if side == "head" else "one nest, ball or reflector per angle on the table"


def _one_point_designs(part: FiveAxisPositionModel, L: str):
    """The designs of :func:`one_point_motions` of axis L, one per branch read at >= 5 distinct points: rows
    ∂p/∂(t ⊗ (1, cos θ, sin θ), ω) of each point (3 per point), unit columns."""
    _, state = part._state(part.theta(part.start_vector()))
    S = _sensitivities(state, L)
    if S is None:
        return []
    theta = part.commands[:, part.machine.axes.index(L)] * DEG
    d = part._dir(L)
    out = []
    for b in ((1.0, -1.0) if d is not None else (None,)):
        sel = np.ones(len(theta), bool) if b is None else d == b
        _, first = np.unique(np.column_stack([part.commands[sel], part.tool[sel]]).round(9), axis=0,
                             return_index=True)
        idx = np.flatnonzero(sel)[first]
        if idx.size < 5:
            continue
        h = np.column_stack([np.ones(idx.size), np.cos(theta[idx]), np.sin(theta[idx])])
        D = np.concatenate([np.einsum("mij,mk->mijk", S[idx, :, :3], h).reshape(idx.size * 3, 9),
                            S[idx, :, 3:].reshape(idx.size * 3, 3)], axis=1)
        out.append(D / np.maximum(np.linalg.norm(D, axis=0), 1e-300))
    return out


def _with_ties(model: FiveAxisPositionModel, J, what: str):
    """(model columns A, nuisance columns N, what) of a Jacobian J (rows, n_params + own), the motions' gauge rows
    appended to A (scaled to its largest column)."""
    n = model.n_params
    A, N = J[:, :n], J[:, n:]
    # (not the full-turn ties: they join a map's two ends, which counted C's angular motions on a thin campaign as
    # the measurement's gauge -- held on 25 commands; the fit keeps them)
    ties = np.array([c.row for c in model.gauge_constraints(full_turns=False)]).reshape(-1, n)
    A = np.vstack([A, ties * (np.linalg.norm(A, axis=0).max() if A.size else 1.0)])
    return A, np.vstack([N, np.zeros((len(ties), N.shape[1]))]), what


def _groups(model: FiveAxisPositionModel) -> Dict[str, np.ndarray]:
    """Indices in x of each parameter group: each location error alone, each error motion's nodes, ``linear``,
    ``tool<m>`` (held ones left out)."""
    em, out = model.errors, {}
    remap = np.full(em.n_params, -1)
    remap[model.free_cols] = np.arange(model.free_cols.size)
    for L in model.machine.rotary if em.location else ():
        s = em.slices[f"location_{L}"]
        out.update({em.names[i]: np.array([i]) for i in range(s.start, s.stop)})
    for jm in em.maps.values():
        out[jm.joint] = np.arange(em.slices[jm.joint].start, em.slices[jm.joint].stop)
    if em.linear_model is not None:  # the linear axes' motions and squareness errors, each alone
        out.update({m: np.arange(em.slices[m].start, em.slices[m].stop) for m in ALL_MOTIONS if m in em.slices})
        out.update({f"{q}_urad": np.array([em.names.index(f"{q}_urad")]) for q in SQUARENESS})
    for g in em.tool_groups:
        out[g] = np.arange(em.slices[g].start, em.slices[g].stop)
    out = {g: remap[idx][remap[idx] >= 0] for g, idx in out.items()}
    return {g: idx for g, idx in out.items() if idx.size}
