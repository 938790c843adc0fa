"""An identified five-axis model written as the files CNCs load (issue 25, item 6; ``docs/cnc_exports.md``).

Every exporter is ``export_<fmt>(machine, error_model, x, path) -> ExportReport`` (``x``: the error model's full
vector, ``error_model.names``, mm and µrad) and has its parser ``load_<fmt>(path, machine, error_model=None)``
returning the machine the file describes (``.points(commands, directions)``: tool points in the workpiece
frame, mm). The report's residual is computed by re-reading the written file and comparing its tool points with
the identified model's (:class:`~olti_drake.model.five_axis_errors.FiveAxisPositionModel`) on 10⁴ random
commands within travel (:mod:`olti_drake.io.cnc_kin`: after the part set-up, and raw).

* ``sinumerik``: swivel data of an orientable toolholder, ``$TC_CARR1..65[n]``: offset vectors l1–l4
  (``$TC_CARR1..6``, ``15..20``), rotary axis vectors v1, v2 (``7..12``), kinematic type (``23``), axis
  identifiers (``21``, ``22``), travel (``30..33``), the fine offsets of l1–l4 (``41..46``, ``55..60``) and of the
  rotary axis offsets (``64``, ``65``; basic ``24``, ``25``). Holds the position and the orientation of both axis
  lines and their zero angles (ISO 230-7 E_X0C, E_Y0C, E_A0C, E_B0C, E_C0C, …); mm, degrees.
* ``fanuc``: tool centre point control parameters (Series 16i/18i/30i): 19680 (mechanical unit type 2, 12, 21),
  19681–19690 (rotary axes: axis number, direction, inclination, rotation direction), 19700–19702 (rotary table
  position), 19703–19705 (intersection offset between the table axes), 19709–19711 (tool axis to tool rotary
  axis), 19712–19714 (between the tool rotary axes), 19666 (tool holder offset); integers of the increment
  system (IS-B 0.001 mm, IS-C 0.0001 mm), field ±99 999 999. Holds the axis lines' positions only.
* ``heidenhain``: KinematicsComp-style compensation tables, one per rotary axis L and component (``L_EXL.COM``
  … ``L_ECL.COM``): the axis' total error (location + error motion, ISO 230-7 / 230-1 names) against the
  commanded angle, forward and reverse (negative direction of traverse) values; mm and degrees.
* ``linuxcnc``: ``xyzac-trt-kins`` HAL pins (``x-rot-point``, ``y-rot-point``, ``z-rot-point``, ``y-offset``,
  ``z-offset``; ``x-offset`` unused by xyzac, ``tool-offset`` left to ``motion.tooloffset.z``) and INI
  ``[JOINT_3]``/``[JOINT_4]`` ``HOME_OFFSET`` corrections of A and C; machine units (mm), degrees.
* ``csv``: every identified value by name (``name,value,unit``); it holds everything.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.cnc_kin import (ExportReport, RigidKinematics, cannot_hold_phrases, check_field, fit_lines,
                                   lines_of, model_points, nominal_kinematics, nonzero_groups, residual)
from olti_drake.model.five_axis import DEG, LINEAR

FORMATS = ("sinumerik", "fanuc", "heidenhain", "linuxcnc", "csv")

_MAPS = "angle-dependent error motions: the format has constants only; their best constant is kept"
_LINEAR = "linear-axis error motions and squareness: no place in this format"
_TOOLS = "tool offsets of tools >= 1 belong to the tool table"


def _write(path, text: str) -> str:
    from olti_drake.io.outputs import writing

    with writing(path) as f:
        f.write(text)
    return str(path)


def _header(comment: str, fmt: str, machine, extra=()) -> list:
    return [f"{comment} olti compensate --cnc {fmt}: {machine.path} (workpiece frame '{machine.workpiece_frame}', "
            f"tool frame '{machine.tool_frame}')",
            f"{comment} machine coordinates: machine axes, origin at the tool point at all-zero commands"] + \
        [f"{comment} {e}" for e in extra]


def _report(fmt, paths, holds, lacks, equivalent, machine, error_model, x, notes=()) -> ExportReport:
    groups = nonzero_groups(error_model, x)
    return ExportReport(fmt, tuple(str(p) for p in paths), tuple(holds), cannot_hold_phrases(groups, lacks),
                        residual(equivalent, machine, error_model, x), tuple(notes))


def _two_axes(kin: RigidKinematics, fmt: str):
    """(type, first, second) of a two-rotary-axis machine: 'P' table/table, 'T' head/head, 'M' head/table."""
    h, t = kin.head, kin.table
    if len(h) + len(t) != 2:
        raise InputError(f"{fmt}: the format describes two rotary axes; machine model {kin.machine.path} has "
                         f"{len(h) + len(t)} ({', '.join(r.letter for r in h + t) or 'none'})")
    if not h:
        return "P", t[0], t[1]
    if not t:
        return "T", h[0], h[1]
    return "M", h[0], t[0]


# =========================================================================== SINUMERIK
def _sinumerik_vectors(kind, first, second, m0):
    """l1..l4 (machine coordinates, mm) of the rotary lines (docs/cnc_exports.md, "SINUMERIK")."""
    p1, p2 = first.pivot - m0, second.pivot - m0
    z = np.zeros(3)
    if kind == "P":
        return {1: z, 2: p1, 3: p2 - p1, 4: -p2}
    if kind == "T":
        return {1: -p1, 2: p1 - p2, 3: p2, 4: z}
    return {1: -p1, 2: p1, 3: p2, 4: -p2}


_L_BASIC = {1: (1, 2, 3), 2: (4, 5, 6), 3: (15, 16, 17), 4: (18, 19, 20)}
_L_FINE = {1: (41, 42, 43), 2: (44, 45, 46), 3: (55, 56, 57), 4: (58, 59, 60)}


def export_sinumerik(machine, error_model, x, path, toolholder: int = 1) -> ExportReport:
    """SINUMERIK swivel data (orientable toolholder ``toolholder``) as a part program of ``$TC_CARR``
    assignments: the nominal chain in the basic parameters, the identified change in the fine offsets
    ($TC_CARR41–46, 55–60 of l1–l4; $TC_CARR64/65 of the rotary axis offsets, −(actual − commanded angle)), the
    identified axis directions in full in v1/v2 ($TC_CARR7–12). ISO 230-7: the line positions (E_X0C, E_Y0C,
    E_Y0A, E_Z0A …) go to l1–l4, the orientations (E_A0C, E_B0C, E_B0A, E_C0A …) to v1/v2, the zero angles
    (E_A0A, E_C0C …) to $TC_CARR64/65."""
    nominal = nominal_kinematics(machine, error_model.tools[0])
    kind, n1, n2 = _two_axes(nominal, "sinumerik")
    fitted = fit_lines(machine, error_model, x, lambda r: (True, True, True))
    lines = lines_of(fitted)
    f1, f2 = lines[n1.letter], lines[n2.letter]
    m0 = nominal.origin
    basic, total = _sinumerik_vectors(kind, n1, n2, m0), _sinumerik_vectors(kind, f1, f2, m0)
    n = int(toolholder)
    out = _header(";", "sinumerik", machine, [
        f"swivel data of toolholder {n}, kinematic type {kind} (T: head/head, P: table/table, M: head/table); "
        "UNITS: mm, degrees",
        "l1-l4, v1, v2 at zero angles; v: the direction about which the tool turns relative to the workpiece "
        "(a table axis' physical direction reversed)",
        "fine offsets ($TC_CARR41-46, 55-60, 64, 65) = identified - nominal; activate with $MC_TOCARR_FINE_CORRECTION"])

    def put(number, value, what):
        text = f'"{value}"' if isinstance(value, str) and number == 23 else (
            value if isinstance(value, str) else f"{value:.6f}")
        out.append(f"$TC_CARR{number}[{n}]={text} ; {what}")

    put(23, kind, "kinematic type")
    put(21, n1.letter, "axis identifier of rotary axis v1")
    put(22, n2.letter, "axis identifier of rotary axis v2")
    for li in (1, 2, 3, 4):
        for number, comp, v in zip(_L_BASIC[li], "xyz", basic[li]):
            put(number, float(v), f"{comp} component of offset vector l{li} (mm)")
    for vi, r in ((1, f1), (2, f2)):
        for k, comp in enumerate("xyz"):
            out.append(f"$TC_CARR{(7, 10)[vi - 1] + k}[{n}]={r.u[k]:.12f} ; {comp} component of rotary axis "
                       f"vector v{vi} ({r.letter})")
    for vi, r in ((1, n1), (2, n2)):
        k = machine.axes.index(r.letter)
        lo, hi = machine.lower[k], machine.upper[k]
        finite = np.isfinite(lo) and np.isfinite(hi)
        put(23 + vi, 0.0, f"offset of rotary axis v{vi} (deg)")
        put(29 + vi, float(lo) if finite else 0.0, f"minimum position of v{vi} (deg; 0 and 0: not checked)")
        put(31 + vi, float(hi) if finite else 0.0, f"maximum position of v{vi} (deg)")
    for li in (1, 2, 3, 4):
        for number, comp, v in zip(_L_FINE[li], "xyz", total[li] - basic[li]):
            put(number, float(v), f"{comp} fine offset of l{li} (mm)")
    for vi, r in ((1, f1), (2, f2)):
        put(63 + vi, -r.offset_deg, f"fine offset of the rotary axis offset of v{vi} ({r.letter}, deg)")
    out.append("M30")
    _write(path, "\n".join(out) + "\n")
    equivalent = load_sinumerik(path, machine, error_model, toolholder)
    return _report("sinumerik", [path], [
        "positions and orientations of both axis lines (l1-l4, v1, v2)", "zero angles ($TC_CARR64/65)"],
        {"motions": _MAPS, "linear": _LINEAR, "tools": _TOOLS}, equivalent, machine, error_model, x,
        ["the workpiece frame's own rotation (the last table axis' tilt carries it) is the part set-up's"])


def _assignments(path, pattern, what: str) -> dict:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{what} {path}: {exc.strerror}") from None
    return {m.groups()[:-1]: m.groups()[-1] for m in re.finditer(pattern, text, re.M)}


def _number(table, key, path, what):
    try:
        return float(table[key])
    except KeyError:
        raise InputError(f"{what} {path}: no {key} value") from None
    except ValueError:
        raise InputError(f"{what} {path}: {key} = {table[key]!r} is not a number") from None


def load_sinumerik(path, machine, error_model=None, toolholder: int = 1) -> RigidKinematics:
    """The machine a SINUMERIK swivel-data file describes (basic + fine values; docs/cnc_exports.md)."""
    what = "SINUMERIK swivel data"
    raw = _assignments(path, r"^\s*\$TC_CARR(\d+)\[(\d+)\]\s*=\s*\"?([^\";\s]+)\"?", what)
    n = str(int(toolholder))
    t = {int(k[0]): v for k, v in raw.items() if k[1] == n}
    if not t:
        raise InputError(f"{what} {path}: no $TC_CARR values of toolholder {n}")
    num = {k: v for k, v in t.items() if k not in (21, 22, 23)}
    get = lambda k: _number(num, k, path, what) if k in num else 0.0  # noqa: E731 (an absent value is 0)
    nominal = nominal_kinematics(machine, (0, 0, 0) if error_model is None else error_model.tools[0])
    kind, n1, n2 = _two_axes(nominal, "sinumerik")
    if t.get(23, "T").upper() != kind or t.get(21) != n1.letter or t.get(22) != n2.letter:
        raise InputError(f"{what} {path}: kinematic type {t.get(23)!r} with axes {t.get(21)}, {t.get(22)} does not "
                         f"match machine model {machine.path} (type {kind}, axes {n1.letter}, {n2.letter})")
    L = {li: np.array([get(a) + get(b) for a, b in zip(_L_BASIC[li], _L_FINE[li])]) for li in (1, 2, 3, 4)}
    v = [np.array([get(k) for k in (s, s + 1, s + 2)]) for s in (7, 10)]
    off = [-(get(24) + get(64)), -(get(25) + get(65))]
    m0 = nominal.origin
    if kind == "P":
        p1, p2, tool, work = L[2], L[2] + L[3], np.zeros(3), L[2] + L[3] + L[4]
    elif kind == "T":
        p1 = -L[1]
        p2 = p1 - L[2]
        tool, work = p2 - L[3], np.zeros(3)
    else:
        p1, p2 = -L[1], L[3]
        tool, work = p1 - L[2], L[3] + L[4]
    lines = {}
    for r, p, u, o in ((n1, p1, v[0], off[0]), (n2, p2, v[1], off[1])):
        if not np.linalg.norm(u) > 0:
            raise InputError(f"{what} {path}: rotary axis vector of {r.letter} is zero")
        lines[r.letter] = type(r)(r.letter, r.side, m0 + p, u / np.linalg.norm(u), o)
    kin = nominal.with_lines(lines)
    return replace(kin, tool=kin.tool + tool, work=kin.work + work)


# =========================================================================== FANUC
_INCREMENT = {"IS-B": 0.001, "IS-C": 0.0001}
_FIELD = 99_999_999


def _fanuc_axis_direction(r):
    """(19682 axis direction 1 X / 2 Y / 3 Z, 19684 rotation direction 0 right-hand / 1 left-hand) of a line:
    the mechanical motion for a positive command (a table turns the opposite way of the tool relative to it)."""
    physical = r.u if r.side == "head" else -r.u
    k = int(np.argmax(np.abs(physical)))
    return k + 1, 0 if physical[k] > 0 else 1


def export_fanuc(machine, error_model, x, path, increment: str = "IS-B") -> ExportReport:
    """FANUC tool centre point control parameters as a listing ``N<number> P<value>`` (integers of the
    ``increment`` system: IS-B 0.001 mm, IS-C 0.0001 mm; field ±99 999 999, a value beyond it refused in one
    line). ISO 230-7: the line positions (E_X0C, E_Y0C, E_Y0A, E_Z0A …) go to 19700–19714; the orientations
    (E_A0C …) have no place (19683/19688 incline an axis in one plane only, written 0) and the zero angles (E_C0C
    …) belong to the axes' reference position shift, not to this series."""
    if increment not in _INCREMENT:
        raise InputError(f"fanuc: increment must be one of {', '.join(_INCREMENT)}, got {increment!r}")
    unit = _INCREMENT[increment]
    nominal = nominal_kinematics(machine, error_model.tools[0])
    kind, n1, n2 = _two_axes(nominal, "fanuc")
    mech = {"P": 12, "T": 2, "M": 21}[kind]
    fitted = lines_of(fit_lines(machine, error_model, x, lambda r: (True, False, False)))
    f1, f2 = fitted[n1.letter], fitted[n2.letter]
    m0 = nominal.origin
    vectors = {}
    if kind == "P":
        vectors[19700], vectors[19703] = f1.pivot - m0, f2.pivot - f1.pivot
    elif kind == "M":
        vectors[19700], vectors[19709] = f2.pivot - m0, f1.pivot - m0
    else:
        vectors[19709], vectors[19712] = f2.pivot - m0, f1.pivot - f2.pivot
    names = {19700: "rotary table position", 19703: "intersection offset between the table's first and second "
             "rotation axes", 19709: "intersection offset from the tool axis to the tool rotation axis",
             19712: "intersection offset between the tool's second and first rotation axes"}
    out = _header(";", "fanuc", machine, [
        f"tool centre point control, mechanical unit type {mech}; lengths in {increment} increments of "
        f"{unit:g} mm, angles in degrees",
        "19682/19687 axis direction 1 X, 2 Y, 3 Z; 19684/19689 rotation direction 0 right-hand, 1 left-hand"])
    out.append(f"N19680 P{mech} ; mechanical unit type")
    for base, r in ((19681, n1), (19686, n2)):
        direction, sense = _fanuc_axis_direction(r)
        out.append(f"N{base} P{machine.axes.index(r.letter) + 1} ; controlled-axis number of {r.letter}")
        out.append(f"N{base + 1} P{direction} ; axis direction of {r.letter}")
        out.append(f"N{base + 2} P0 ; inclination angle of {r.letter} (deg)")
        out.append(f"N{base + 3} P{sense} ; rotation direction of {r.letter}")
    out.append("N19666 P0 ; tool holder offset (the tool's length goes to the tool offset memory)")
    for number, vec in vectors.items():
        for k, comp in enumerate("XYZ"):
            value = check_field(round(float(vec[k]) / unit), _FIELD,
                                f"fanuc: parameter {number + k} ({names[number]}, {comp})", f"x {unit:g} mm")
            out.append(f"N{number + k} P{int(value)} ; {names[number]} {comp} = {value * unit:.4f} mm")
    _write(path, "\n".join(out) + "\n")
    equivalent = load_fanuc(path, machine, error_model, increment)
    return _report("fanuc", [path], ["positions of both axis lines (19700-19714)"], {
        "orientation": "orientation of the axis lines: the axis directions are the machine axes",
        "zero": "zero angles: the rotary axes' reference position shift, outside the 19700 series",
        "motions": _MAPS, "linear": _LINEAR, "tools": _TOOLS}, equivalent, machine, error_model, x,
        [f"lengths rounded to {unit:g} mm"])


def load_fanuc(path, machine, error_model=None, increment: str = "IS-B") -> RigidKinematics:
    """The machine a FANUC parameter listing describes: nominal axis directions, the pivots from 19700–19714."""
    what = "FANUC parameters"
    raw = _assignments(path, r"^\s*N(\d+)\s*P(-?\d+)", what)
    p = {int(k[0]): v for k, v in raw.items()}
    unit = _INCREMENT.get(increment)
    if unit is None:
        raise InputError(f"fanuc: increment must be one of {', '.join(_INCREMENT)}, got {increment!r}")
    nominal = nominal_kinematics(machine, (0, 0, 0) if error_model is None else error_model.tools[0])
    kind, n1, n2 = _two_axes(nominal, "fanuc")
    mech = {"P": 12, "T": 2, "M": 21}[kind]
    if int(_number(p, 19680, path, what)) != mech:
        raise InputError(f"{what} {path}: mechanical unit type {p[19680]} does not match machine model "
                         f"{machine.path} (type {mech})")
    for base, r in ((19681, n1), (19686, n2)):
        if _number(p, base + 2, path, what) != 0:
            raise InputError(f"{what} {path}: parameter {base + 2}: an inclined rotation axis is not read")
        if (int(_number(p, base + 1, path, what)), int(_number(p, base + 3, path, what))) != \
                _fanuc_axis_direction(r):
            raise InputError(f"{what} {path}: parameters {base + 1}/{base + 3}: {r.letter}'s direction differs from "
                             f"machine model {machine.path}")
    vec = lambda n: np.array([_number(p, n + k, path, what) for k in range(3)]) * unit  # noqa: E731
    m0 = nominal.origin
    if kind == "P":
        p1 = vec(19700)
        p2 = p1 + vec(19703)
    elif kind == "M":
        p2, p1 = vec(19700), vec(19709)
    else:
        p2 = vec(19709)
        p1 = p2 + vec(19712)
    return nominal.with_lines({n1.letter: type(n1)(n1.letter, n1.side, m0 + p1, n1.u),
                               n2.letter: type(n2)(n2.letter, n2.side, m0 + p2, n2.u)})


# =========================================================================== LinuxCNC
_TRT = "xyzac-trt-kins"


def _check_trt(kin: RigidKinematics):
    t = kin.table
    ok = (not kin.head and [r.letter for r in t] == ["A", "C"]
          and np.allclose(t[0].u, [-1, 0, 0], atol=1e-9) and np.allclose(t[1].u, [0, 0, -1], atol=1e-9))
    if not ok:
        have = ", ".join(f"{r.side} {r.letter}" for r in kin.head + kin.table) or "no rotary axes"
        raise InputError(f"linuxcnc: {_TRT} is a tilting table A (about +x) carrying a rotary table C (about +z); "
                         f"machine model {kin.machine.path} has {have}")
    return t[0], t[1]


def export_linuxcnc(machine, error_model, x, path) -> ExportReport:
    """``xyzac-trt-kins`` HAL pin values (``path``, ``setp`` lines) and the INI ``HOME_OFFSET`` corrections of
    A ([JOINT_3]) and C ([JOINT_4]) (``path`` with suffix ``.ini``). ISO 230-7: E_X0C, E_Y0C → ``x-rot-point``,
    ``y-rot-point``; E_Y0A, E_Z0A → ``y-offset``, ``z-offset`` (A's pivot relative to C's); E_A0A, E_C0C → the
    HOME_OFFSET corrections (actual − commanded angle, deg: add them to the joints' HOME_OFFSET). The axis
    lines' orientations (E_B0A, E_C0A, E_A0C, E_B0C) have no pin. A swivel head is refused."""
    nominal = nominal_kinematics(machine, error_model.tools[0])
    _check_trt(nominal)
    fitted = fit_lines(machine, error_model, x, lambda r: (True, False, True))
    A, C = _check_trt(fitted)
    m0 = nominal.origin
    rc = C.pivot - m0
    rot = np.array([rc[0], rc[1], nominal.line("C").pivot[2] - m0[2]])
    pins = {"x-rot-point": rot[0], "y-rot-point": rot[1], "z-rot-point": rot[2], "x-offset": 0.0,
            "y-offset": A.pivot[1] - m0[1] - rot[1], "z-offset": A.pivot[2] - m0[2] - rot[2]}
    hal = _header("#", "linuxcnc", machine, [
        f"{_TRT} pins; UNITS: machine units = mm, degrees",
        "rot-point: C's centre of rotation; y-/z-offset: A's centre of rotation relative to C's",
        "tool-offset: net it to motion.tooloffset.z as usual (0 for the measured tool)"])
    hal += [f"setp {_TRT}.{k} {v:.6f}" for k, v in pins.items()]
    ini_path = Path(path).with_suffix(".ini")
    ini = _header("#", "linuxcnc", machine, ["HOME_OFFSET corrections (deg): actual - commanded angle at zero; "
                                             "ADD them to the joints' present HOME_OFFSET"])
    for joint, r in ((3, A), (4, C)):
        ini += [f"[JOINT_{joint}]", f"# {r.letter}", f"HOME_OFFSET = {r.offset_deg:.9f}"]
    _write(path, "\n".join(hal) + "\n")
    _write(ini_path, "\n".join(ini) + "\n")
    equivalent = load_linuxcnc(path, machine, error_model)
    return _report("linuxcnc", [path, ini_path], [
        "positions of the A and C lines (rot-point, y-/z-offset)", "zero angles (HOME_OFFSET corrections)"], {
        "orientation": f"orientation of the axis lines: {_TRT} turns about x and z",
        "motions": _MAPS, "linear": _LINEAR, "tools": _TOOLS}, equivalent, machine, error_model, x)


def load_linuxcnc(path, machine, error_model=None) -> RigidKinematics:
    """The machine ``xyzac-trt-kins`` computes with the HAL pins of ``path`` and the HOME_OFFSET corrections of
    ``path`` with suffix ``.ini`` (0 when absent): x = r + Rz(−c)·(Rx(−a)·(J − r − d) + d)."""
    what = f"LinuxCNC {_TRT} pins"
    raw = _assignments(path, rf"^\s*setp\s+{re.escape(_TRT)}\.([a-z-]+)\s+(\S+)", what)
    p = {k[0]: v for k, v in raw.items()}
    nominal = nominal_kinematics(machine, (0, 0, 0) if error_model is None else error_model.tools[0])
    A, C = _check_trt(nominal)
    g = lambda k: _number(p, k, path, what)  # noqa: E731
    if g("x-offset") != 0:
        raise InputError(f"{what} {path}: x-offset = {p['x-offset']}: xyzac-trt-kins does not use it")
    r = np.array([g("x-rot-point"), g("y-rot-point"), g("z-rot-point")])
    d = np.array([0.0, g("y-offset"), g("z-offset")])
    off = {3: 0.0, 4: 0.0}
    ini = Path(path).with_suffix(".ini")
    if ini.is_file():
        joint = None
        for line in ini.read_text(encoding="utf-8").splitlines():
            s = line.split("#")[0].strip()
            m = re.fullmatch(r"\[JOINT_(\d+)\]", s)
            if m:
                joint = int(m.group(1))
            elif s.startswith("HOME_OFFSET") and joint in off:
                try:
                    off[joint] = float(s.split("=", 1)[1])
                except (IndexError, ValueError):
                    raise InputError(f"LinuxCNC INI {ini}: [JOINT_{joint}] {s!r} is not 'HOME_OFFSET = number'") \
                        from None
    m0 = nominal.origin
    pa = np.array([A.pivot[0], m0[1] + r[1] + d[1], m0[2] + r[2] + d[2]])
    pc = np.array([m0[0] + r[0], m0[1] + r[1], C.pivot[2]])
    return nominal.with_lines({"A": type(A)("A", "table", pa, A.u, off[3]),
                               "C": type(C)("C", "table", pc, C.u, off[4])})


# =========================================================================== HEIDENHAIN
_KC_COLUMN = {c: f"C{k + 1}" for k, c in enumerate("XYZABC")}


class TableKinematics:
    """The machine a set of angle-dependent tables describes: the nominal loop with each rotary axis' total
    error (X, Y, Z mm; A, B, C µrad) interpolated in its commanded angle, forward (+1) or reverse (−1), placed
    as the error model places it (:func:`~olti_drake.model.five_axis_errors.evaluate_loop`)."""

    def __init__(self, machine, tables, tool_offset_mm=(0.0, 0.0, 0.0)):
        self.machine, self.tables, self.tool = machine, tables, np.asarray(tool_offset_mm, float)

    def points(self, commands, directions=None) -> np.ndarray:
        from olti_drake.model.five_axis_errors import evaluate_loop

        c = self.machine.check_commands(commands)
        d = np.ones((len(c), len(self.machine.rotary))) if directions is None else np.asarray(directions, float)

        def errors(L, q):
            out = np.zeros((len(q), 6))
            if L not in self.tables:
                return out
            grid, fwd, rev = self.tables[L]
            up = d[:, self.machine.rotary.index(L)] > 0
            for r in range(6):
                out[:, r] = np.where(up, np.interp(q, grid, fwd[:, r]), np.interp(q, grid, rev[:, r]))
            return out
        return evaluate_loop(self.machine, c, errors, None, np.broadcast_to(self.tool, (len(c), 3)))[0]


def _total_tables(machine, error_model, x):
    """{L: (grid_deg, forward (n, 6), reverse (n, 6))}: location + error motions at the grid nodes (a model
    without motions: the location errors at the travel's ends)."""
    em, x = error_model, np.asarray(x, float)
    out = {}
    for L in machine.rotary:
        loc = em.location_values(x, L)
        if (L, "X") in em.maps:
            grid = em.maps[(L, "X")].emap.grid_deg
            fwd, rev = np.tile(loc, (grid.size, 1)), np.tile(loc, (grid.size, 1))
            for r, c in enumerate("XYZABC"):
                vals = x[em.slices[f"E_{c}{L}"]]
                fwd[:, r] += vals[:grid.size]
                rev[:, r] += vals[grid.size:] if em.bidirectional else vals[:grid.size]
        else:
            k = machine.axes.index(L)
            grid = np.array([v if np.isfinite(v) else s for v, s in ((machine.lower[k], -180.0),
                                                                      (machine.upper[k], 180.0))])
            fwd = rev = np.tile(loc, (2, 1))
        out[L] = (grid, fwd, rev)
    return out


def _heidenhain_table(L: str, c: str) -> str:
    """The name of rotary axis L's table of component c (X, Y, Z, A, B, C): ``<L>_E<c><L>.COM``."""
    return f"{L}_E{c}{L}.COM"


def export_heidenhain(machine, error_model, x, path) -> ExportReport:
    """KinematicsComp-style tables in the directory ``path``: ``<L>_E<c><L>.COM`` for rotary axis L and component
    c (X, Y, Z radial/axial, mm; A, B, C tilt and angular positioning, degrees), rows ``NR AXISPOS FORWARD
    REVERSE``: the commanded angle (deg), the axis' total error approached in the positive direction, and in the
    negative direction (KinematicsComp's COMPTAB column C1–C6 of the rotary axis; the location errors E_X0C …
    are the tables' constant part). Errors, not corrections: the control computes with them, placed before the
    affected axis (HEIDENHAIN's recommended scheme; ISO 230-7 carrier placement)."""
    d = Path(path)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for L, (grid, fwd, rev) in _total_tables(machine, error_model, x).items():
        for r, c in enumerate("XYZABC"):
            name = _heidenhain_table(L, c)
            linear = c in LINEAR
            scale = 1.0 if linear else 1e-6 / DEG
            fmt = "{:.7f}" if linear else "{:.10f}"
            text = [f"BEGIN {name} {'MM' if linear else 'DEG'}"] + _header(";", "heidenhain", machine, [
                f"rotary axis {L}, E_{c}{L} (ISO 230-1) with its location error (ISO 230-7), KinematicsComp column "
                f"{_KC_COLUMN[c]}; {'mm' if linear else 'degrees'}; AXISPOS: commanded {L} (deg)",
                "FORWARD: approached in the positive direction; REVERSE: in the negative direction"])
            text.append(f"{'NR':<6}{'AXISPOS':>14}{'FORWARD':>20}{'REVERSE':>20}")
            for i, q in enumerate(grid):
                text.append(f"{i:<6}{q:>14.6f}{fmt.format(fwd[i, r] * scale):>20}"
                            f"{fmt.format(rev[i, r] * scale):>20}")
            text.append("[END]")
            paths.append(_write(d / name, "\n".join(text) + "\n"))
    equivalent = load_heidenhain(path, machine, error_model)
    return _report("heidenhain", paths, ["location errors and all six bidirectional error motions per rotary axis"],
                   {"linear": _LINEAR, "tools": _TOOLS}, equivalent, machine, error_model, x)


def load_heidenhain(path, machine, error_model=None) -> TableKinematics:
    """The machine the tables in directory ``path`` describe (a missing table: that component is 0)."""
    tables = {}
    for L in machine.rotary:
        grid, fwd, rev = None, None, None
        for r, c in enumerate("XYZABC"):
            f = Path(path) / _heidenhain_table(L, c)
            if not f.is_file():
                continue
            rows = []
            for line in f.read_text(encoding="utf-8").splitlines():
                parts = line.split(";")[0].split()
                if len(parts) == 4 and parts[0].isdigit():
                    try:
                        rows.append([float(v) for v in parts[1:]])
                    except ValueError:
                        raise InputError(f"HEIDENHAIN table {f}: row {parts[0]} is not numbers") from None
            if not rows:
                raise InputError(f"HEIDENHAIN table {f}: no rows")
            a = np.array(rows)
            if grid is None:
                grid, fwd, rev = a[:, 0], np.zeros((len(a), 6)), np.zeros((len(a), 6))
            elif a.shape[0] != grid.size or np.any(a[:, 0] != grid):
                raise InputError(f"HEIDENHAIN table {f}: its AXISPOS differ from {L}'s other tables")
            scale = 1.0 if c in LINEAR else DEG * 1e6
            fwd[:, r], rev[:, r] = a[:, 1] * scale, a[:, 2] * scale
        if grid is not None:
            if np.any(np.diff(grid) <= 0):
                raise InputError(f"HEIDENHAIN tables of {L} in {path}: AXISPOS must increase")
            tables[L] = (grid, fwd, rev)
    if not tables:
        raise InputError(f"HEIDENHAIN tables {path}: no <axis>_E<c><axis>.COM table of {', '.join(machine.rotary)}")
    return TableKinematics(machine, tables, (0, 0, 0) if error_model is None else error_model.tools[0])


# =========================================================================== CSV
def _unit(name: str) -> str:
    if name.endswith("_mm") or "_mm[" in name:
        return "mm"
    if name.endswith("_urad") or "_urad[" in name:
        return "urad"
    return "mm" if len(name) > 3 and name[2] in LINEAR and name[3] in LINEAR else "urad"


class ModelKinematics:
    """The identified model itself at a parameter vector read back (``points``: its tool points, tool 0)."""

    def __init__(self, machine, error_model, x):
        self.machine, self.error_model, self.x = machine, error_model, np.asarray(x, float)

    def points(self, commands, directions=None) -> np.ndarray:
        return model_points(self.machine, self.error_model, self.x, commands, directions)


def export_csv(machine, error_model, x, path) -> ExportReport:
    """Every value of the error model by its ISO name: ``name,value,unit`` (mm, µrad; error motions per node,
    ``E_CC_forward_urad[3]`` at the grid angle in column ``grid_deg``)."""
    x = np.asarray(x, float)
    grid = {}
    for jm in error_model.maps.values():
        g = jm.emap.grid_deg
        for i, n in enumerate(error_model.names[error_model.slices[jm.joint]]):
            grid[n] = g[i % g.size]
    lines = [f"# olti compensate --cnc csv: {machine.path} (workpiece frame '{machine.workpiece_frame}', tool frame "
             f"'{machine.tool_frame}'); sense and placement: docs/five_axis.md", "name,value,unit,grid_deg"]
    for n, v in zip(error_model.names, x):
        lines.append(f"{n},{float(v)!r},{_unit(n)},{float(grid[n])!r}" if n in grid else f"{n},{float(v)!r},{_unit(n)},")
    _write(path, "\n".join(lines) + "\n")
    equivalent = load_csv(path, machine, error_model)
    return _report("csv", [path], ["every identified value"], {}, equivalent, machine, error_model, x)


def load_csv(path, machine, error_model) -> ModelKinematics:
    """The model at the values of a CSV export; every name of ``error_model`` must be there, once."""
    values = {}
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    except OSError as exc:
        raise InputError(f"CSV {path}: {exc.strerror}") from None
    for i, r in enumerate(rows[1:], start=2):
        try:
            values[r[0]] = float(r[1])
        except (IndexError, ValueError):
            raise InputError(f"CSV {path}: row {i}: expected name,value,unit") from None
    missing = [n for n in error_model.names if n not in values]
    extra = [n for n in values if n not in set(error_model.names)]
    if missing or extra:
        raise InputError(f"CSV {path}: {'missing ' + ', '.join(missing[:3]) if missing else ''}"
                         f"{'; ' if missing and extra else ''}{'unknown ' + ', '.join(extra[:3]) if extra else ''} "
                         f"(the error model has {error_model.n_params} values)")
    return ModelKinematics(machine, error_model, [values[n] for n in error_model.names])


EXPORTERS = {"sinumerik": export_sinumerik, "fanuc": export_fanuc, "heidenhain": export_heidenhain,
             "linuxcnc": export_linuxcnc, "csv": export_csv}
LOADERS = {"sinumerik": load_sinumerik, "fanuc": load_fanuc, "heidenhain": load_heidenhain,
           "linuxcnc": load_linuxcnc, "csv": load_csv}


#: The name ``export`` gives each format's file (HEIDENHAIN: the directory of its tables) in the export directory.
EXPORT_NAMES = {"sinumerik": "swivel_data.mpf", "fanuc": "tcp_parameters.txt", "heidenhain": "kinematicscomp",
                "linuxcnc": "xyzac-trt.hal", "csv": "identified.csv"}


def _check_format(fmt: str) -> None:
    if fmt not in EXPORTERS:
        raise InputError(f"--cnc: unknown format {fmt!r} (one of {', '.join(FORMATS)})")


def cnc_file_names(fmt: str, machine) -> tuple:
    """Every file :func:`export` of ``fmt`` writes for ``machine``, relative to its export directory (``/``
    separated), so that a command can check them before any work: ``swivel_data.mpf``; ``tcp_parameters.txt``;
    ``kinematicscomp/<L>_E<c><L>.COM`` for every rotary axis L and component c of X, Y, Z, A, B, C (12 on a
    two-rotary-axis machine); ``xyzac-trt.hal`` and ``xyzac-trt.ini``; ``identified.csv``. Unknown ``fmt``: a
    one-line InputError."""
    _check_format(fmt)
    name = EXPORT_NAMES[fmt]
    if fmt == "heidenhain":
        return tuple(f"{name}/{_heidenhain_table(L, c)}" for L in machine.rotary for c in "XYZABC")
    if fmt == "linuxcnc":
        return name, str(Path(name).with_suffix(".ini"))
    return (name,)


def export(fmt: str, machine, error_model, x, out_dir) -> ExportReport:
    """``export_<fmt>`` into ``out_dir`` under the format's default name (:data:`EXPORT_NAMES`; for ``olti
    compensate --cnc FORMAT --tables DIR``): ``swivel_data.mpf``, ``tcp_parameters.txt``, ``kinematicscomp/``,
    ``xyzac-trt.hal`` (+ .ini), ``identified.csv``; every file it writes: :func:`cnc_file_names`."""
    _check_format(fmt)
    os.makedirs(out_dir, exist_ok=True)
    return EXPORTERS[fmt](machine, error_model, x, os.path.join(out_dir, EXPORT_NAMES[fmt]))


__all__ = ["FORMATS", "EXPORTERS", "LOADERS", "EXPORT_NAMES", "export", "cnc_file_names", "ExportReport"] + \
    [f"{k}_{f}" for k in ("export", "load") for f in FORMATS]
