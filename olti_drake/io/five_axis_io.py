"""Five-axis campaigns, points and results (``shared/spec/formats.md``, "Five-axis machine tools"; issue 25).

* :func:`read_five_axis_campaign` -- the campaign CSV: command columns ``x_cmd_mm, y_cmd_mm, z_cmd_mm`` and a
  ``<letter>_cmd_deg`` column for every rotary axis of the model (mm, deg), optional approach directions
  ``dir_x`` … ``dir_<letter>`` (±1, formats.md's direction rule: +1 when the axis' last motion before the reading
  was in its positive sense), optional ``tool`` and ``valid``; then per row one reading: a distance (``station``,
  ``displacement_mm``, ``station_frame`` = ``workpiece`` | ``base``, default ``base``; paper 001 Eq. (3)), an
  R-test / 3D-probe displacement (``nest``, ``dx_mm, dy_mm, dz_mm`` in the workpiece frame; ISO 10791-6 K4) or a
  tracker point (``x_mm, y_mm, z_mm`` in the tracker's frame, ``station_frame`` saying where it stands, the
  tracker set-up ``station``, default 0). A mixed campaign leaves the cells of the other kinds empty. Every bad
  input is one :class:`~olti_drake.errors.InputError` line naming the file and line.
* :func:`write_five_axis_campaign` -- the writer, columns in the order above.
* :func:`read_five_axis_points` -- the commands to predict.
* :func:`machine5_result_dict` / :func:`load_machine5_result` -- the ``olti-machine5/1`` result by the one codec
  (:func:`olti_drake.io.documents.result_document`), and back to (machine, error model, x, covariance).

Units: mm, deg in files; µrad for the angular errors in results.
"""

import csv
import dataclasses
import hashlib
import os
from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np

from olti_drake.errors import InputError

LINEAR_COLUMNS = ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm")
ROTARY_LETTERS = ("A", "B", "C")
FRAMES = ("base", "workpiece")
#: The column order of a written campaign (formats.md): commands, directions, tool, then the readings.
COLUMN_ORDER = (LINEAR_COLUMNS + tuple(f"{a.lower()}_cmd_deg" for a in ROTARY_LETTERS)
                + tuple(f"dir_{a}" for a in "xyzabc") + ("tool", "station", "displacement_mm", "nest", "dx_mm",
                                                         "dy_mm", "dz_mm", "x_mm", "y_mm", "z_mm", "station_frame",
                                                         "valid"))
_INTEGER = ("tool", "station", "nest", "valid") + tuple(f"dir_{a}" for a in "xyzabc")
KINDS = {"distance": ("displacement_mm",), "nest": ("dx_mm", "dy_mm", "dz_mm"), "tracker": ("x_mm", "y_mm", "z_mm")}


def command_columns(axes) -> tuple:
    """The command columns of a machine's axes (``x_cmd_mm`` …, ``a_cmd_deg`` …), in ``axes`` order."""
    return tuple(f"{a.lower()}_cmd_mm" if a in "XYZ" else f"{a.lower()}_cmd_deg" for a in axes)


def write_five_axis_campaign(path, columns: dict) -> None:
    """Write a five-axis campaign CSV (formats.md): the ``columns`` given (name -> sequence, one entry per row;
    ``station_frame`` strings, empty strings or NaN for a cell of another reading kind), in
    :data:`COLUMN_ORDER`; refused in one line for an unknown column or unequal lengths."""
    from olti_drake.io.outputs import writing

    unknown = [c for c in columns if c not in COLUMN_ORDER]
    if unknown:
        raise InputError(f"{os.fspath(path)}: unknown five-axis campaign column {unknown[0]!r} (formats.md: "
                         f"{', '.join(COLUMN_ORDER)})")
    names = [c for c in COLUMN_ORDER if c in columns]
    n = {len(columns[c]) for c in names}
    if len(n) != 1:
        raise InputError(f"{os.fspath(path)}: the columns differ in length ({sorted(n)})")
    with writing(path, measurement=True, newline="\n") as f:
        f.write("# olti_drake five-axis campaign (formats.md, Five-axis machine tools): mm, deg; valid 0 = beam "
                "lost\n")
        f.write(",".join(names) + "\n")
        for r in range(n.pop()):
            f.write(",".join(_cell(c, columns[c][r]) for c in names) + "\n")


def _cell(column: str, v) -> str:
    if isinstance(v, str):
        return v
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if column in _INTEGER:
        return "%d" % int(v)
    s = ("%.6f" if column.endswith("_cmd_mm") or column.endswith("_cmd_deg") else "%.9f") % float(v)
    return "0" if s.lstrip("-").strip("0.") == "" else s


# ------------------------------------------------------------------------------------------- reading
@dataclass
class FiveAxisCampaign:
    """A five-axis campaign, valid rows only. Row k: ``commands[k]`` (columns ``axes``, mm / deg),
    ``directions[k]`` (±1 per rotary axis, or None for the whole campaign), ``tool[k]``, ``kind[k]``
    ('distance', 'nest', 'tracker'), ``frame[k]`` ('base' | 'workpiece': where the station / tracker stands;
    'workpiece' for nests), ``group[k]`` (station, nest or tracker set-up index, as in the file), ``reading[k]``
    (displacement in column 0, or the 3 coordinates, mm), ``line[k]`` (file line)."""

    source: str
    axes: tuple
    commands: np.ndarray
    directions: Optional[np.ndarray]
    tool: np.ndarray
    kind: np.ndarray
    frame: np.ndarray
    group: np.ndarray
    reading: np.ndarray
    line: np.ndarray
    digest: dict

    @property
    def n_readings(self) -> int:
        return len(self.line)

    @property
    def n_tools(self) -> int:
        return int(self.tool.max()) + 1 if len(self.tool) else 1


def canonical_rows(campaign) -> np.ndarray:
    """A rank of every campaign row by its content (kind, frame, station / nest / set-up, tool, commands,
    directions, reading): the same rows in any file order get the same ranks (identical rows tie)."""
    c = campaign
    keys = [c.kind, c.frame, c.group, c.tool, *c.commands.T, *(() if c.directions is None else c.directions.T),
            *c.reading.T]
    codes = [np.unique(k, return_inverse=True)[1].ravel() for k in keys]
    order = np.lexsort(codes[::-1])
    rank = np.empty(len(order), int)
    rank[order] = np.arange(len(order))
    return rank


def in_canonical_order(campaign) -> "FiveAxisCampaign":
    """The campaign with its rows in :func:`canonical_rows`' order (each row keeps its file line): a fit of it is the
    same, to the last bit, in any file order -- sums over the readings are taken in one order (a fit on 40
    commands with the linear axes identified moved by 3e-6 µrad between two orders on another BLAS kernel)."""
    order = np.argsort(canonical_rows(campaign), kind="stable")
    take = (lambda a: None if a is None else np.asarray(a)[order])
    return dataclasses.replace(campaign, commands=take(campaign.commands), directions=take(campaign.directions),
                               tool=take(campaign.tool), kind=take(campaign.kind), frame=take(campaign.frame),
                               group=take(campaign.group), reading=take(campaign.reading), line=take(campaign.line))


def _rows(path):
    """(header line, header, [(line, fields)]) of a CSV file, ``#`` comments and blank lines skipped."""
    from olti_drake.io.csvio import read_text

    name = os.fspath(path)
    rows = [(i + 1, s) for i, s in enumerate(read_text(path).splitlines()) if s.strip() and not
            s.lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{name}: empty file (no header row)")
    cols = [c.strip() for c in next(csv.reader([rows[0][1]]))]
    dup = [c for c in cols if cols.count(c) > 1]
    if dup:
        raise InputError(f"{name}:{rows[0][0]}: duplicate column '{dup[0]}'")
    if len(rows) == 1:
        raise InputError(f"{name}: empty file (no data rows)")
    data = []
    for line, s in rows[1:]:
        fields = [f.strip() for f in next(csv.reader([s]))]
        if len(fields) != len(cols):
            raise InputError(f"{name}:{line}: expected {len(cols)} fields as in the header, got {len(fields)}")
        data.append((line, fields))
    return rows[0][0], cols, data


def _check_axis_columns(name, hline, cols, axes, what: str) -> None:
    """Refuse a missing command column of the model's axes, or a command / direction column of an axis the model
    lacks (one line naming the file, the header line and the column)."""
    needed = command_columns(axes)
    missing = [c for c in needed if c not in cols]
    if missing:
        raise InputError(f"{name}:{hline}: missing required column '{missing[0]}' ({what} has the axes "
                         f"{', '.join(axes)}; header has {', '.join(cols)})")
    for a in "XYZABC":
        if a in axes:
            continue
        for c in command_columns((a,)) + (f"dir_{a.lower()}",):
            if c in cols:
                raise InputError(f"{name}:{hline}: column '{c}' is for axis {a}, which {what} does not have "
                                 f"(its axes: {', '.join(axes)})")


def _number(name, line, column, raw, integer=False) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise InputError(f"{name}:{line}: column '{column}': "
                         f"{'missing value' if not raw else repr(raw) + ' is not a number'}") from None
    if not np.isfinite(v):
        raise InputError(f"{name}:{line}: column '{column}': {raw!r} is not finite")
    if integer and v != round(v):
        raise InputError(f"{name}:{line}: column '{column}': {raw!r} is not a whole number")
    return v


def _row_kind(name, line, get) -> str:
    """The reading kind of a row: the one whose cells are filled (all of them), refused when none or several."""
    filled = [k for k, cs in KINDS.items() if any(get(c) for c in cs)]
    if len(filled) != 1:
        what = "no reading" if not filled else "readings of several kinds (" + ", ".join(filled) + ")"
        raise InputError(f"{name}:{line}: {what}: a row holds one of displacement_mm (with station), dx_mm, dy_mm, "
                         f"dz_mm (with nest) or x_mm, y_mm, z_mm (tracker)")
    k = filled[0]
    empty = [c for c in KINDS[k] if not get(c)]
    if empty:
        raise InputError(f"{name}:{line}: column '{empty[0]}': missing value")
    if k == "distance" and not get("station"):
        raise InputError(f"{name}:{line}: column 'station': missing value (a distance reading needs its station)")
    if k == "nest" and not get("nest"):
        raise InputError(f"{name}:{line}: column 'nest': missing value (an R-test reading needs its nest)")
    return k


def read_five_axis_campaign(path, machine) -> FiveAxisCampaign:
    """The five-axis campaign at ``path`` for ``machine`` (:class:`~olti_drake.model.five_axis.FiveAxisMachine`),
    checked per formats.md (module docstring); rows with ``valid`` 0 are skipped. Commands outside the travel
    are refused naming the line and axis."""
    name = os.fspath(path)
    hline, cols, data = _rows(path)
    axes = tuple(machine.axes)
    _check_axis_columns(name, hline, cols, axes, f"machine model {machine.path}")
    rotary = tuple(machine.rotary)
    dir_cols = [f"dir_{a.lower()}" for a in axes if f"dir_{a.lower()}" in cols]
    rot_dirs = [f"dir_{a.lower()}" for a in rotary]
    if dir_cols and not all(c in cols for c in rot_dirs):
        raise InputError(f"{name}:{hline}: missing column '{next(c for c in rot_dirs if c not in cols)}': give the "
                         f"approach direction of every rotary axis ({', '.join(rot_dirs)}) or of none")
    if not any(c in cols for cs in KINDS.values() for c in cs):
        raise InputError(f"{name}:{hline}: no reading columns: a five-axis campaign has displacement_mm (distances), "
                         f"dx_mm, dy_mm, dz_mm (R-test) or x_mm, y_mm, z_mm (tracker)")
    for k, cs in KINDS.items():
        some = [c for c in cs if c in cols]
        if some and len(some) != len(cs):
            raise InputError(f"{name}:{hline}: missing column '{next(c for c in cs if c not in cols)}' (with "
                             f"'{some[0]}')")
    need = {"distance": "station", "nest": "nest"}
    for k, c in need.items():
        if KINDS[k][0] in cols and c not in cols:
            raise InputError(f"{name}:{hline}: missing required column '{c}' (with '{KINDS[k][0]}')")
    index = {c: i for i, c in enumerate(cols)}
    cmd_cols = command_columns(axes)
    out = {k: [] for k in ("commands", "dirs", "tool", "kind", "frame", "group", "reading", "line")}
    for line, fields in data:
        def get(c, fields=fields):
            return fields[index[c]] if c in index else ""
        if get("valid") and _number(name, line, "valid", get("valid"), True) not in (0.0, 1.0):
            raise InputError(f"{name}:{line}: column 'valid': {get('valid')!r} is not 0 or 1")
        if get("valid") and float(get("valid")) == 0.0:
            continue
        out["commands"].append([_number(name, line, c, get(c)) for c in cmd_cols])
        dirs = [_number(name, line, c, get(c), True) for c in dir_cols]
        bad = [c for c, v in zip(dir_cols, dirs) if v not in (-1.0, 1.0)]
        if bad:
            raise InputError(f"{name}:{line}: column '{bad[0]}': {get(bad[0])!r} is not +1 or -1 (the approach "
                             f"direction, formats.md)")
        out["dirs"].append([_number(name, line, c, get(c), True) for c in rot_dirs] if dir_cols else [])
        out["tool"].append(_number(name, line, "tool", get("tool"), True) if get("tool") else 0.0)
        kind = _row_kind(name, line, get)
        frame = get("station_frame") or "base"
        if frame not in FRAMES:
            raise InputError(f"{name}:{line}: column 'station_frame': {frame!r} is not workpiece or base")
        if kind == "nest":
            if get("station_frame") and frame != "workpiece":
                raise InputError(f"{name}:{line}: column 'station_frame': an R-test reading is in the workpiece "
                                 f"frame (formats.md), got {frame!r}")
            frame = "workpiece"
        group = {"distance": "station", "nest": "nest", "tracker": "station"}[kind]
        g = _number(name, line, group, get(group), True) if get(group) else 0.0
        if g < 0 or out["tool"][-1] < 0:
            bad = group if g < 0 else "tool"
            raise InputError(f"{name}:{line}: column '{bad}': {get(bad)!r} is not an index >= 0")
        vals = [_number(name, line, c, get(c)) for c in KINDS[kind]]
        out["kind"].append(kind)
        out["frame"].append(frame)
        out["group"].append(int(g))
        out["reading"].append(vals + [0.0] * (3 - len(vals)))
        out["line"].append(line)
    if not out["line"]:
        raise InputError(f"{name}: no valid readings (every row has valid 0)")
    commands = np.array(out["commands"], float)
    line = np.array(out["line"], int)
    try:
        machine.check_commands(commands)
    except InputError as e:
        row = int(str(e).split("row ", 1)[1].split(":", 1)[0]) if "row " in str(e) else 0
        raise InputError(f"{name}:{line[row]}: " + str(e).split(": ", 2)[-1]) from None
    kind, frame, group = (np.array(out[k]) for k in ("kind", "frame", "group"))
    _check_station_frames(name, kind, frame, group, line)
    return FiveAxisCampaign(name, axes, commands, np.array(out["dirs"], float) if dir_cols else None,
                            np.array(out["tool"], int), kind, frame, group, np.array(out["reading"], float), line,
                            _digest(commands, np.array(out["reading"], float)))


def _check_station_frames(name, kind, frame, group, line) -> None:
    """One station (or tracker set-up) stands in one frame: refuse the first line that moves it to the other."""
    for k in ("distance", "tracker"):
        for g in np.unique(group[kind == k]):
            rows = np.flatnonzero((kind == k) & (group == g))
            other = rows[frame[rows] != frame[rows[0]]]
            if other.size:
                what = "station" if k == "distance" else "tracker set-up"
                raise InputError(f"{name}:{line[other[0]]}: column 'station_frame': {what} {g} is on the "
                                 f"{frame[rows[0]]} frame at line {line[rows[0]]}, {frame[other[0]]} here")


def _digest(commands, readings) -> dict:
    from olti_drake.io.csvio import data_digest

    return data_digest(commands, readings)


def read_five_axis_points(path, machine):
    """(commands (M, n_axes), directions (M, n_rotary) or None, tool (M,), the table with ``_line``) of a
    ``points.csv`` (formats.md: the command columns, optional directions and ``tool``)."""
    from olti_drake.io.csvio import read_table

    name = os.fspath(path)
    hline, cols, _ = _rows(path)
    _check_axis_columns(name, hline, cols, tuple(machine.axes), f"machine model {machine.path}")
    rot_dirs = [f"dir_{a.lower()}" for a in machine.rotary]
    has_dirs = any(c in cols for c in rot_dirs)
    if has_dirs and not all(c in cols for c in rot_dirs):
        raise InputError(f"{name}:{hline}: missing column '{next(c for c in rot_dirs if c not in cols)}': give the "
                         f"approach direction of every rotary axis ({', '.join(rot_dirs)}) or of none")
    cmd = command_columns(machine.axes)
    table = read_table(path, cmd, optional=rot_dirs + ["tool"], integer=rot_dirs + ["tool"])
    for c in rot_dirs if has_dirs else ():
        bad = np.flatnonzero(~np.isin(table[c], (-1.0, 1.0)))
        if bad.size:
            raise InputError(f"{name}:{table['_line'][bad[0]]}: column '{c}': {table[c][bad[0]]:g} is not +1 or -1")
    commands = np.column_stack([table[c] for c in cmd])
    try:
        machine.check_commands(commands)
    except InputError as e:
        row = int(str(e).split("row ", 1)[1].split(":", 1)[0]) if "row " in str(e) else 0
        raise InputError(f"{name}:{table['_line'][row]}: " + str(e).split(": ", 2)[-1]) from None
    tool = table["tool"].astype(int) if "tool" in table else np.zeros(len(commands), int)
    if np.any(tool < 0):
        raise InputError(f"{name}:{table['_line'][int(np.argmax(tool < 0))]}: column 'tool': not an index >= 0")
    dirs = np.column_stack([table[c] for c in rot_dirs]) if has_dirs else None
    return commands, dirs, tool, table


# ------------------------------------------------------------------------------------------- results
def file_sha256(path) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


@dataclass
class LinearFrom:
    """The linear axes of a five-axis machine taken from an earlier ``olti-volumetric/1`` result: the motions in
    the five-axis loop's convention (:class:`~olti_drake.model.five_axis_errors.RelocatedMotions`), the file and
    its sha256."""

    motions: object
    path: str
    sha256: str
    model: object = None
    params: Optional[np.ndarray] = None
    covariance: Optional[np.ndarray] = None

    def motion_parameters(self) -> np.ndarray:
        """Indices of the result's parameters that move the linear axes (motions and squareness, not the tool
        offsets) and carry an uncertainty."""
        tools = np.zeros(len(self.params), bool)
        for g in self.model.tool_groups:
            tools[self.model.slices[g]] = True
        return np.flatnonzero(~tools & (np.diag(self.covariance) > 0))

    def relocated(self, params):
        """The motions of the result's model at ``params`` (its parameter vector), about the loop's frames."""
        from olti_drake.model.five_axis_errors import RelocatedMotions

        return RelocatedMotions(self.model.motions(params), self.motions.offsets)

    def entry(self, reference: str) -> dict:
        """The result's ``linear_from`` (the file as ``reference`` names it, relative to the result)."""
        from olti_drake.formats import VOLUMETRIC_RESULT

        return {"file": reference, "sha256": self.sha256, "format": VOLUMETRIC_RESULT,
                "held": "the 18 error motions and 3 squareness errors of the linear axes, fixed (not estimated)",
                "reference_point": "the volumetric result's spindle reference point is the tool frame's origin "
                                   "(docs/five_axis.md)"}


def load_linear_from(path, machine, commands=None, source: str = "the campaign") -> "LinearFrom":
    """The linear-axis motions of the volumetric result at ``path`` for ``machine`` (formats.md, *Machine tool in
    3D*), checked in one line naming the file: an ``olti-volumetric/1`` result (another kind refused); the machine
    has X, Y and Z, each moving the tool point +1 mm along its letter per mm of command relative to the workpiece
    at zero commands (the volumetric positions are the commands, ISO 841's sense); the same topology (which axes
    the table carries); a travel that covers ``commands`` (M, n_axes) mm/deg of ``source``."""
    from olti_drake.io.volumetric_io import load_volumetric_result
    from olti_drake.model.five_axis import LINEAR
    from olti_drake.model.five_axis_errors import carriage_offsets, linear_config

    name = os.fspath(path)
    result = load_volumetric_result(path)
    if tuple(machine.linear) != tuple(LINEAR):
        raise InputError(f"--linear {name}: machine model {machine.path} has the linear axes "
                         f"{', '.join(machine.linear) or 'none'}; a volumetric result is of X, Y and Z")
    zero = np.zeros((1, len(machine.axes))).clip(machine.lower, machine.upper)
    for k, a in enumerate(LINEAR):
        step = zero.copy()
        step[0, k] += 1.0
        slope = _nominal_points(machine, step) - _nominal_points(machine, zero)
        if not np.allclose(slope, np.eye(3)[k], atol=1e-9):
            raise InputError(f"--linear {name}: in machine model {machine.path} +1 mm of {a} moves the tool "
                             f"{np.round(slope[0], 6).tolist()} mm relative to the workpiece, not +1 along "
                             f"{a.lower()}: the volumetric result's positions would not be this machine's {a} "
                             f"commands")
    cfg, ours = result.model.config, linear_config(machine)
    if (tuple(cfg.tool_chain), tuple(cfg.work_chain)) != (tuple(ours.tool_chain), tuple(ours.work_chain)):
        def named(c):  # (the --topology that gives this stacking, when one does)
            return f" (--topology {c.topology})" if c.topology else " (no --topology gives it)"
        raise InputError(f"--linear {name}: topology tool_chain {list(cfg.tool_chain)}, work_chain "
                         f"{list(cfg.work_chain)}{named(cfg)}; machine model {machine.path} has tool_chain "
                         f"{list(ours.tool_chain)}, work_chain {list(ours.work_chain)}{named(ours)}")
    for k, a in enumerate(LINEAR if commands is not None else ()):
        q = np.asarray(commands, float)[:, machine.axes.index(a)]
        lo, hi = cfg.travel_mm[a]
        if q.min() < lo - 1e-6 or q.max() > hi + 1e-6:
            raise InputError(f"--linear {name}: travel_mm {a} [{lo:g}, {hi:g}] does not cover the {a} commands of "
                             f"{source}, [{q.min():g}, {q.max():g}] mm")
    from olti_drake.model.five_axis_errors import RelocatedMotions

    return LinearFrom(RelocatedMotions(result.motions, carriage_offsets(machine)), name, file_sha256(path),
                      result.model, np.asarray(result.params, float), np.asarray(result.covariance, float))


def _nominal_points(machine, commands):
    """The nominal tool points (workpiece frame, mm) without the travel check (a unit step may leave it)."""
    from olti_drake.model.five_axis_plan import _tool_points

    return _tool_points(machine, commands, (0.0, 0.0, 0.0))


#: The layout's keys that are labels, not values (left out of the ``uncertainty``).
_LABELS = ("station_labels", "station_frames", "tracker_frame_stands_on", "held", "measurement_sigmas_mm")


def machine5_result_dict(ident, fit, machine_reference: str, notes=(),
                         linear_reference: Optional[str] = None) -> dict:
    """The ``olti-machine5/1`` result (formats.md) of a five-axis identification ``ident``
    (:class:`olti_drake.estimation.five_axis.FiveAxisIdentification`) and its ``fit``, by the one codec
    (:func:`~olti_drake.io.documents.result_document`): the machine file (as ``machine_reference`` names it,
    relative to the result) and its sha256, the frames and axes, the error model's settings, the errors by ISO
    name (``layout``: location errors in mm and µrad, error motions with ``grid_deg``, ``forward``/``reverse``),
    the tool offsets, stations / nests / tracker frames, the held (dropped) groups, the gauge, the uncertainty in
    the same keys (k = 1) and the covariance (:func:`olti_drake.io.serial_io.covariance_entry`); with linear axes
    from a volumetric result (``--linear``), ``linear_from`` (:meth:`LinearFrom.entry`, the file as
    ``linear_reference`` names it)."""
    from olti_drake.io.documents import result_document
    from olti_drake.io.serial_io import covariance_entry

    m, em = ident.machine, ident.errors
    values = {"model": ident.model_name,
              "machine": {"file": machine_reference, "sha256": file_sha256(m.path),
                          "workpiece_frame": m.workpiece_frame, "tool_frame": m.tool_frame, "axes": list(m.axes)},
              "error_model": ident.error_model_settings(),
              **ident.layout(fit.x),
              "tool_offset_mm": em.tool_offsets(ident.position_model.theta(fit.x)).tolist(),
              "dropped": dict(ident.dropped)}
    linear = getattr(ident, "linear_from", None)
    if linear is not None:
        values["linear_from"] = linear.entry(linear_reference or linear.path)
    unc = {k: v for k, v in ident.layout(fit.std, uncertainty=True).items() if k not in _LABELS}
    if em.linear_model is not None:
        unc["linear"] = linear_uncertainty(ident, fit, values["linear"])
    return result_document("machine5", values, fit, gauge=ident.gauge, uncertainty=unc,
                           n_readings=ident.campaign.n_readings, campaign=ident.campaign.digest,
                           notes=list(notes), tail=covariance_entry(fit))


def linear_uncertainty(ident, fit, values: dict) -> dict:
    """The identified linear axes' standard uncertainties (k = 1) in the keys of their ``values``
    (:func:`~olti_drake.model.five_axis_errors.linear_layout`): every coefficient's, the squareness', and every
    stated value's from the covariance of the linear block (:func:`~olti_drake.io.volumetric_io.motion_std`;
    held motions and fixed coefficients: 0)."""
    from olti_drake.io.volumetric_io import motion_std
    from olti_drake.model.five_axis_errors import linear_layout

    em, pm = ident.errors, ident.position_model
    k, f, s = pm.n_params, pm.free_cols, em.slices["linear"]
    C = np.zeros((em.n_params, em.n_params))
    C[np.ix_(f, f)] = np.asarray(fit.covariance, float)[:k, :k]
    C = C[s, s]
    out = linear_layout(em.linear_model, np.sqrt(np.maximum(np.diag(C), 0.0)), uncertainty=True)
    positions = {e["axis"]: e["positions_mm"] for e in values["error_motions"].values()}
    for name, u in motion_std(em.linear_model, C, positions).items():
        out["error_motions"][name]["values"] = u.tolist()
    return out


@dataclass
class Machine5Result:
    """A loaded ``olti-machine5/1`` result: the machine, the error model, x over ``names`` (the model's free
    parameters), the covariance of x (None when not stored), the held groups and the document."""

    machine: object
    errors: object
    names: tuple
    x: np.ndarray
    covariance: Optional[np.ndarray]
    held: tuple
    document: dict

    def position_model(self, commands, directions=None, tool=None):
        """The tool points of ``commands`` in the workpiece frame (mm) on the identified errors."""
        from olti_drake.model.five_axis_errors import FiveAxisPositionModel

        return FiveAxisPositionModel(self.machine, self.errors, commands, directions, tool, frame="workpiece",
                                     held=self.held)

    @property
    def lack_of_fit_mm(self) -> float:
        """The model error (mm, k = 1) every predicted tool point shares, added in quadrature to the u the
        covariance gives: ``covariance.lack_of_fit_mm`` (0 when absent; the maps' representation between their
        nodes, :meth:`~olti_drake.estimation.five_axis.FiveAxisIdentification.representation`), read and checked
        as a serial result's (:func:`olti_drake.io.serial_io.lack_of_fit_of`)."""
        from olti_drake.io.serial_io import lack_of_fit_of

        return lack_of_fit_of(self.document)


def load_machine5_result(path) -> Machine5Result:
    """Read an ``olti-machine5/1`` result back to (machine, error model, x, covariance): the machine file
    (relative to the result) checked against its sha256, the error model rebuilt from ``error_model``, the
    values of x taken by name from the result's layout (location errors, error-motion nodes, tool offsets)."""
    from olti_drake.io.documents import read_result
    from olti_drake.io.serial_io import _load_covariance
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_errors import FiveAxisErrors, FiveAxisPositionModel

    name = os.fspath(path)
    _, doc = read_result(path, ("machine5",), "olti predict")
    try:
        mach = doc["machine"]
        file = mach["file"] if os.path.isabs(mach["file"]) else os.path.join(os.path.dirname(os.path.abspath(name)),
                                                                              mach["file"])
        settings, held = doc["error_model"], tuple(doc.get("held", ()))
    except (KeyError, TypeError) as e:
        raise InputError(f"{name}: missing key {e} of an olti-machine5/1 result") from None
    if not os.path.isfile(file):
        raise InputError(f"{name}: key 'machine.file': {file} not found")
    if file_sha256(file) != mach.get("sha256"):
        raise InputError(f"{name}: key 'machine.sha256': {file} has changed since the identification")
    machine = FiveAxisMachine.from_file(file, mach["workpiece_frame"], mach["tool_frame"])
    settings = dict(settings)
    if settings.pop("linear", None) == "identify":  # (identified with the rotary axes, on these knots)
        linear, settings["knot_spacing_mm"] = "identify", _knot_spacing_of(settings, name)
    else:
        linear = _linear_of(doc, name, machine)
    try:
        em = FiveAxisErrors(machine, **settings, linear=linear)
    except TypeError as e:
        raise InputError(f"{name}: key 'error_model': {e}") from None
    pm = FiveAxisPositionModel(machine, em, np.zeros((1, len(machine.axes))).clip(machine.lower, machine.upper),
                               np.ones((1, len(machine.rotary))) if em.bidirectional and em.maps else None,
                               held=held)
    theta = _theta_from_layout(doc, em, name)
    x = theta[pm.free_cols]
    C, cnames = _load_covariance(doc, name, pm)
    if C is not None:
        idx = [cnames.index(n) for n in pm.names]
        C = C[np.ix_(idx, idx)]
    return Machine5Result(machine, em, pm.names, x, C, held, doc)


def _knot_spacing_of(settings: dict, name: str) -> float:
    v = settings.pop("knot_spacing_mm", None)
    if not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
        raise InputError(f"{name}: key 'error_model.knot_spacing_mm': expected a spacing > 0 (mm), got {v!r}")
    return float(v)


def _linear_of(doc: dict, name: str, machine):
    """The linear axes' motions of a result identified with ``--linear`` (its ``linear_from``: the file relative to
    the result, checked against its sha256), or None."""
    entry = doc.get("linear_from")
    if entry is None:
        return None
    file = entry.get("file", "") if isinstance(entry, dict) else ""
    file = file if os.path.isabs(file) else os.path.join(os.path.dirname(os.path.abspath(name)), file)
    if not os.path.isfile(file):
        raise InputError(f"{name}: key 'linear_from.file': {file} not found")
    if file_sha256(file) != entry.get("sha256"):
        raise InputError(f"{name}: key 'linear_from.sha256': {file} has changed since the identification")
    return load_linear_from(file, machine).motions


def _theta_from_layout(doc: dict, em, name: str) -> np.ndarray:
    """The error model's full vector from a result's ``location_errors``, ``error_motions``, ``linear`` (identified
    linear axes) and ``tool_offset_mm``."""
    from olti_drake.io.csvio import json_numbers

    theta = em.zeros()
    loc = doc.get("location_errors", {})
    for i, n in enumerate(em.names):
        if n in loc:
            theta[i] = float(loc[n])
    for (L, c), jm in em.maps.items():
        entry = doc.get("error_motions", {}).get(jm.joint)
        if entry is None:
            raise InputError(f"{name}: missing key 'error_motions.{jm.joint}'")
        n = jm.emap.n_nodes
        vals = [json_numbers(entry, name, "forward", (n,), label=f"error_motions.{jm.joint}.forward")]
        if em.bidirectional:
            vals.append(json_numbers(entry, name, "reverse", (n,), label=f"error_motions.{jm.joint}.reverse"))
        theta[em.slices[jm.joint]] = np.concatenate(vals)
    if em.linear_model is not None:
        from olti_drake.model.five_axis_errors import linear_from_layout

        theta[em.slices["linear"]] = linear_from_layout(em.linear_model, doc.get("linear"), name)
    tools = np.asarray(doc.get("tool_offset_mm", em.tools.tolist()), float).reshape(-1, 3)
    for m, g in enumerate(em.tool_groups, start=1):
        theta[em.slices[g]] = tools[m] - em.tools[m]
    return theta


def write_predictions(path, commands, directions, tool, machine, p, u) -> None:
    """``P.csv``: the command columns (and directions, ``tool``) repeated, then ``x_mm, y_mm, z_mm`` (the tool
    point in the workpiece frame) and ``u_x_mm, u_y_mm, u_z_mm`` (k = 1), mm."""
    from olti_drake.io.csvio import write_table

    cols: Dict[str, object] = {c: commands[:, k] for k, c in enumerate(command_columns(machine.axes))}
    fmt = {c: "%.6f" for c in cols}
    for k, a in enumerate(machine.rotary if directions is not None else ()):
        cols[f"dir_{a.lower()}"] = directions[:, k]
        fmt[f"dir_{a.lower()}"] = "%d"
    cols["tool"], fmt["tool"] = tool, "%d"
    for k, c in enumerate("xyz"):
        cols[f"{c}_mm"], fmt[f"{c}_mm"] = p[:, k], "%.9f"
    for k, c in enumerate("xyz"):
        cols[f"u_{c}_mm"], fmt[f"u_{c}_mm"] = u[:, k], "%.9f"
    write_table(path, cols, fmt, comments=["olti_drake five-axis prediction (formats.md): tool points in the "
                                           "workpiece frame, mm; u k = 1"])
