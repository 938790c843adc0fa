"""What the CNC exporters share (issue 25, item 6; ``docs/cnc_exports.md``): the rigid kinematics a controller's
five-axis data describe, its fit to an identified five-axis model, the residual a file leaves, and the report.

:class:`RigidKinematics` is the machine a kinematics file describes: the nominal machine of the model file, its
linear axes as pure translations along the machine axes, and each rotary axis as a line -- a pivot point and a
direction -- with a zero-angle offset. Directions are in the sense of the tool relative to the workpiece (the
loop's sense of :class:`~olti_drake.model.five_axis.FiveAxisMachine`): a positive command turns the tool about
``u`` relative to the workpiece, so a table axis' ``u`` is its physical turning direction reversed, as the
controllers enter it (SINUMERIK: "the axis direction is reversed" for a rotary table). ISO 230-7 names: the
radial position of the line (``E_X0C``, ``E_Y0C`` …) is the pivot's perpendicular components, its orientation
(``E_A0C``, ``E_B0C`` …) the tilt of ``u``, the zero angle (``E_C0C`` …) the offset.

Machine coordinates (every file): the machine axes, origin at the tool point (tool 0) at all-zero commands, so
the linear commands X, Y, Z are the tool point's machine coordinates at zero rotary angles.

**Part set-up.** No kinematics file holds where the workpiece frame sits on the table: the part's set-up (work
offset and basic rotation, probed after the compensation) does. Every residual is therefore stated twice: after
the best rigid transform of the workpiece frame (``max_um``/``rms_um``, the headline) and raw (``raw_max_um``,
``raw_rms_um``: the file alone against the identified model's tool points). Units: mm, deg, µrad as named.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Dict, List, Tuple

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.five_axis import DEG, ROTARY, AxisLink, FiveAxisMachine
from olti_drake.model.frames import rigid_fit, rotation_vector

#: Commands of the residual: 10⁴ uniform within travel (a continuous axis: one turn), seeded.
N_RESIDUAL, SEED = 10_000, 0


def _rot(axis, angle_rad) -> np.ndarray:
    """(M, 3, 3) rotations about the unit ``axis`` by ``angle_rad`` (M,) (Rodrigues)."""
    a = np.asarray(axis, float)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    s, c = np.sin(angle_rad)[:, None, None], np.cos(angle_rad)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _small_rotation(w) -> np.ndarray:
    """3×3 rotation of the rotation vector ``w`` (rad)."""
    t = float(np.linalg.norm(w))
    return np.eye(3) if t == 0 else _rot(np.asarray(w) / t, np.array([t]))[0]


@dataclass(frozen=True)
class RotaryLine:
    """A rotary axis as the controller sees it: ``pivot`` (mm, base frame at zero commands), unit ``u`` (the tool
    turns about ``u`` relative to the workpiece for a positive command), ``offset_deg`` (actual angle − command)
    and ``side`` ('head' | 'table')."""

    letter: str
    side: str
    pivot: np.ndarray
    u: np.ndarray
    offset_deg: float = 0.0


@dataclass(frozen=True)
class RigidKinematics:
    """Tool points in the workpiece frame of a machine described by rotary lines (module docstring).

    ``linear``: {letter: (column, unit direction of the tool relative to the workpiece, base frame)}; ``head``:
    the head rotary axes base → tool; ``table``: the table rotary axes base → workpiece; ``tool``: the tool point
    (mm, base frame, all commands 0); ``work``/``work_R``: the workpiece frame's origin and orientation in the
    base frame at zero commands. Table-side linear axes carry the rotary table, head-side ones the rotary head
    (checked by :func:`nominal_kinematics`)."""

    machine: FiveAxisMachine
    linear: Dict[str, Tuple[int, np.ndarray]]
    head: Tuple[RotaryLine, ...]
    table: Tuple[RotaryLine, ...]
    tool: np.ndarray
    work: np.ndarray
    work_R: np.ndarray

    @property
    def origin(self) -> np.ndarray:
        """The machine coordinates' origin (mm, base frame): the nominal tool point at zero commands."""
        return self.tool

    def line(self, letter: str) -> RotaryLine:
        return next(r for r in self.head + self.table if r.letter == letter)

    def with_lines(self, lines) -> "RigidKinematics":
        """A copy with the rotary lines ``lines`` ({letter: RotaryLine}) replaced."""
        return replace(self, head=tuple(lines.get(r.letter, r) for r in self.head),
                       table=tuple(lines.get(r.letter, r) for r in self.table))

    def points(self, commands, directions=None) -> np.ndarray:
        """(M, 3) mm: tool points in the workpiece frame at ``commands`` (M, n_axes) (directions: ignored, the
        file's constants hold for both)."""
        c = self.machine.check_commands(commands)
        col = {a: k for k, a in enumerate(self.machine.axes)}
        x = np.broadcast_to(self.tool, (len(c), 3)).copy()
        for r in reversed(self.head):  # the axis nearest the tool turns first
            R = _rot(r.u, (c[:, col[r.letter]] + r.offset_deg) * DEG)
            x = r.pivot + np.einsum("mij,mj->mi", R, x - r.pivot)
        for k, d in self.linear.values():
            x = x + c[:, k, None] * d
        for r in self.table:  # base outward: the tool relative to the turned table
            R = _rot(r.u, (c[:, col[r.letter]] + r.offset_deg) * DEG)
            x = r.pivot + np.einsum("mij,mj->mi", R, x - r.pivot)
        return (x - self.work) @ self.work_R


def nominal_kinematics(machine: FiveAxisMachine, tool_offset_mm=(0.0, 0.0, 0.0)) -> RigidKinematics:
    """The nominal machine of the model file as :class:`RigidKinematics` (equal to ``machine.tool_points`` to
    rounding). Refused in one line when a rotary axis carries a linear axis on its side (the controllers' chains
    have the linear axes next to the base)."""
    T, acc = [], np.eye(4)
    for e in machine.loop:
        T.append(acc)
        acc = acc @ (e if isinstance(e, np.ndarray) else np.eye(4))
    T.append(acc)
    base_inv = np.linalg.inv(T[machine.base_index])
    linear, head, table = {}, [], []
    for k, e in enumerate(machine.loop):
        if not isinstance(e, AxisLink):
            continue
        P = base_inv @ T[k]
        u = P[:3, :3] @ e.axis
        if e.kind == "prismatic":
            linear[e.letter] = (e.column, u)
            continue
        line = RotaryLine(e.letter, e.side, P[:3, 3].copy(), u / np.linalg.norm(u))
        (head if e.side == "head" else table).append((k, line))
    for side, links in (("table", range(machine.base_index - 1, -1, -1)),
                        ("head", range(machine.base_index, len(machine.loop)))):
        seen_rotary = None
        for k in links:  # base outward
            e = machine.loop[k]
            if isinstance(e, AxisLink) and e.kind == "revolute":
                seen_rotary = e.letter
            elif isinstance(e, AxisLink) and seen_rotary:
                raise InputError(f"machine model {machine.path}: rotary axis {seen_rotary} carries linear axis "
                                 f"{e.letter}; the controllers' five-axis data have the linear axes next to the base")
    table.sort(key=lambda kl: -kl[0])  # base outward
    end = base_inv @ T[-1]
    tool = end[:3, 3] + end[:3, :3] @ np.asarray(tool_offset_mm, float)
    return RigidKinematics(machine, linear, tuple(l for _, l in head), tuple(l for _, l in table), tool,
                           base_inv[:3, 3].copy(), base_inv[:3, :3].copy())


# --------------------------------------------------------------------------- commands and residuals
def random_commands(machine: FiveAxisMachine, n: int = N_RESIDUAL, seed: int = SEED):
    """(commands (n, n_axes), directions (n, n_rotary) ±1): uniform within travel, seeded."""
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(machine.lower), machine.lower, -180.0)
    hi = np.where(np.isfinite(machine.upper), machine.upper, 180.0)
    c = lo + (hi - lo) * rng.random((n, len(machine.axes)))
    d = rng.choice([-1.0, 1.0], size=(n, len(machine.rotary)))
    return c, d


def model_points(machine, error_model, x, commands, directions) -> np.ndarray:
    """(M, 3) mm: the identified model's tool points (tool 0, workpiece frame) at x (the error model's full
    vector, ``error_model.names``)."""
    from olti_drake.model.five_axis_errors import FiveAxisPositionModel

    x = np.asarray(x, float)
    if x.shape != (error_model.n_params,):
        raise InputError(f"x: expected the error model's {error_model.n_params} values (error_model.names), got "
                         f"shape {x.shape}")
    return FiveAxisPositionModel(machine, error_model, commands, directions).positions(x)


def compare(file_points, model_points_) -> dict:
    """Residual of a file's tool points against the model's (µm): after the part set-up (best rigid transform of
    the workpiece frame) and raw; the set-up itself (translation mm, rotation vector µrad)."""
    raw = np.linalg.norm(file_points - model_points_, axis=1)
    R, t = rigid_fit(file_points, model_points_)
    after = np.linalg.norm(file_points @ R.T + t - model_points_, axis=1)
    w = rotation_vector(R)
    return {"max_um": float(after.max() * 1e3), "rms_um": float(np.sqrt(np.mean(after ** 2)) * 1e3),
            "raw_max_um": float(raw.max() * 1e3), "raw_rms_um": float(np.sqrt(np.mean(raw ** 2)) * 1e3),
            "setup_translation_mm": t.tolist(), "setup_rotation_urad": (w * 1e6).tolist()}


def residual(equivalent, machine, error_model, x, n: int = N_RESIDUAL, seed: int = SEED) -> dict:
    """:func:`compare` of ``equivalent.points`` (the machine a file describes) with the identified model on
    :func:`random_commands` (n, seed)."""
    c, d = random_commands(machine, n, seed)
    return compare(equivalent.points(c, d), model_points(machine, error_model, x, c, d))


# --------------------------------------------------------------------------- fitting a format's constants
def fit_lines(machine, error_model, x, holds: Callable[[RotaryLine], Tuple[bool, bool, bool]],
              n: int = 3000, seed: int = SEED + 1) -> RigidKinematics:
    """The format's best rigid kinematics for the identified model: per rotary axis the pivot's two perpendicular
    components, the tilt of ``u`` (two) and the zero-angle offset, each where ``holds(line)`` -> (pivot, tilt,
    offset) says the format has it, fitted by least squares to the model's tool points on ``n`` random commands
    together with the part set-up (rigid, not written). A small ridge (10⁻³ on the constants, 10⁻² on
    the set-up, per mm and mrad) picks, where the constants trade with the set-up (a table axis' zero angle with the part's
    rotation), the file holding what it can and the smallest set-up."""
    nominal = nominal_kinematics(machine, error_model.tools[0])
    c, d = random_commands(machine, n, seed)
    target = model_points(machine, error_model, x, c, d)
    specs = []  # (letter, kind, basis vector)
    for r in nominal.head + nominal.table:
        pivot, tilt, offset = holds(r)
        n1 = np.cross(r.u, np.eye(3)[int(np.argmin(np.abs(r.u)))])
        n1 /= np.linalg.norm(n1)
        n2 = np.cross(r.u, n1)
        specs += [(r.letter, "pivot", v) for v in (n1, n2) if pivot]
        specs += [(r.letter, "tilt", v) for v in (n1, n2) if tilt]
        specs += [(r.letter, "offset", None)] if offset else []

    def build(p):
        lines = {}
        for r in nominal.head + nominal.table:
            piv, u, off = r.pivot.copy(), r.u.copy(), r.offset_deg
            for (letter, kind, v), val in zip(specs, p):
                if letter != r.letter:
                    continue
                if kind == "pivot":
                    piv = piv + val * v
                elif kind == "tilt":
                    u = u + val * 1e-3 * v  # (mrad)
                else:
                    off = off + val * 1e-3 / DEG  # (mrad)
            lines[r.letter] = replace(r, pivot=piv, u=u / np.linalg.norm(u), offset_deg=off)
        return nominal.with_lines(lines)

    k = len(specs)

    def fun(p):
        pts = build(p[:k]).points(c)
        pts = pts @ _small_rotation(p[k:k + 3] * 1e-3).T + p[k + 3:]
        return np.concatenate([(pts - target).ravel(), 1e-3 * p[:k], 1e-2 * p[k:]])

    p = np.zeros(k + 6)  # Gauss-Newton (the tool points are nearly linear in these small constants)
    for _ in range(8):
        r0 = fun(p)
        J = np.empty((r0.size, p.size))
        for j in range(p.size):
            dp = np.zeros(p.size)
            dp[j] = 1e-6
            J[:, j] = (fun(p + dp) - r0) / 1e-6
        step = np.linalg.lstsq(J, -r0, rcond=None)[0]
        cost = r0 @ r0
        while np.sum(fun(p + step) ** 2) > cost and np.max(np.abs(step)) > 1e-12:
            step = step / 2  # (a step that does not lower the cost is halved)
        p = p + step
        if np.max(np.abs(step)) < 1e-10:
            break
    return build(p[:k])


# --------------------------------------------------------------------------- what a format cannot hold
def nonzero_groups(error_model, x, tol: float = 1e-12) -> Dict[str, List[str]]:
    """{kind: [names]} of the model's non-zero values: 'position' (radial location E_X0C …), 'orientation'
    (E_A0C …, the tilts), 'zero' (E_C0C …), 'axial' (E_Z0C), 'motions' (E_XC …, per motion), 'linear',
    'tools'."""
    from olti_drake.model.five_axis_errors import radial

    x = np.asarray(x, float)
    out = {k: [] for k in ("position", "orientation", "zero", "axial", "motions", "linear", "tools")}
    em = error_model
    for L in em.machine.rotary if em.location else ():
        s = em.slices[f"location_{L}"]
        for name, v in zip(em.names[s], x[s]):
            if abs(v) <= tol:
                continue
            comp = name[2]
            kind = ("zero" if comp == L else "orientation" if comp in ROTARY else
                    "position" if comp in radial(L) else "axial")
            out[kind].append(name)
    for (L, c), jm in em.maps.items():
        if np.any(np.abs(x[em.slices[jm.joint]]) > tol):
            out["motions"].append(jm.joint)
    if em.linear_model is not None and np.any(np.abs(x[em.slices["linear"]]) > tol):
        out["linear"].append("linear")
    if em.linear_motions is not None:
        out["linear"].append("linear (known motions)")
    for g in em.tool_groups:
        if np.any(np.abs(x[em.slices[g]]) > tol):
            out["tools"].append(g)
    return out


@dataclass
class ExportReport:
    """What an exporter wrote and what its format leaves: ``format``, ``paths``, ``holds`` (phrases),
    ``cannot_hold`` (phrases naming the ISO values the file does not carry), ``residual`` (:func:`compare` of
    the re-read file against the identified model on 10⁴ random commands, µm), ``notes``."""

    format: str
    paths: Tuple[str, ...]
    holds: Tuple[str, ...]
    cannot_hold: Tuple[str, ...]
    residual: dict
    notes: Tuple[str, ...] = field(default_factory=tuple)

    @property
    def max_um(self) -> float:
        return self.residual["max_um"]

    @property
    def rms_um(self) -> float:
        return self.residual["rms_um"]

    def describe(self) -> str:
        r = self.residual
        lines = [f"{self.format}: wrote {', '.join(self.paths)}",
                 f"  holds: {'; '.join(self.holds)}",
                 f"  cannot hold: {'; '.join(self.cannot_hold) or 'nothing of this model'}",
                 f"  residual after the part set-up: max {r['max_um']:.3f} um, RMS {r['rms_um']:.3f} um "
                 f"(raw: max {r['raw_max_um']:.3f} um, RMS {r['raw_rms_um']:.3f} um; 10^4 random commands)"]
        return "\n".join(lines + [f"  note: {n}" for n in self.notes])


def check_field(value: float, limit: float, what: str, unit: str) -> float:
    """``value`` if |value| ≤ ``limit``, else a one-line InputError naming the parameter and its field."""
    if not np.isfinite(value) or abs(value) > limit:
        raise InputError(f"{what} = {value:.6g} {unit} does not fit the format's field (|value| <= {limit:g} {unit})")
    return value


def cannot_hold_phrases(groups: Dict[str, List[str]], lacks: Dict[str, str]) -> Tuple[str, ...]:
    """Phrases for the model's non-zero groups the format lacks: ``lacks`` {kind: why}."""
    out = []
    for kind, why in lacks.items():
        if groups.get(kind):
            out.append(f"{', '.join(groups[kind])} ({why})")
    return tuple(out)


def lines_of(kin: RigidKinematics) -> Dict[str, RotaryLine]:
    return {r.letter: r for r in kin.head + kin.table}


def optional(v, default):
    return default if v is None else v


__all__ = ["RigidKinematics", "RotaryLine", "ExportReport", "nominal_kinematics", "random_commands", "residual",
           "compare", "fit_lines", "model_points", "nonzero_groups", "check_field"]
