"""Laser trackers' point exports in, as the point campaign of formats.md (``olti import-points``; issue 26, item 2).

Two export layouts are read:

- **generic CSV** (``--format csv``): a header row, then one point per row; the column map ``--columns
  name=Point,x=X,y=Y,z=Z,time=Timestamp`` names the header's columns (default ``name=name,x=x,y=y,z=z,
  time=time``; ``name`` and ``time`` are optional, wanted only by the matching that uses them). Comma, semicolon
  or tab separated (as the header is).
- **SpatialAnalyzer-style ASCII points** (``--format sa``): one point per line, ``Collection Group Target X Y Z``
  (SA's "Collection Group target" name option; "Group target", "target" and one ``Collection::Group::Target``
  token are read alike), space, tab or comma separated; lines starting ``//`` (SA's version, frame and axis
  comments) or ``#`` are comments. The last three fields are X Y Z; the fields before them are the name (joined
  by ``::``). A comment ``// Units: Meters`` (any of mm, millimeters, m, meters, in, inches) states the units.

``--format auto`` takes the SA layout when the first data line ends in three numbers, else the CSV. Units:
``--units mm|m|in``, else the SA header's, else mm; a header and ``--units`` that disagree are refused.

Matching to the robot's joint log (a CSV with ``theta1_deg`` .. ``thetaN_deg``, optional ``dir1`` .. ``dirN`` and
``valid``, and a ``name`` or ``point`` column and/or a ``time_s`` (seconds) or ``timestamp`` (ISO 8601) column):

- ``name``: exact; a log name matches a point's full name, else its target name (the last part) when no two
  points share that target name.
- ``time``: the export's time (seconds, or ISO 8601) nearest to the log row's, within ``max_dt_s``; pairs are
  taken closest first, so each log row and each point is used at most once and the result does not depend on
  either file's row order.

Unmatched rows are **skipped and counted** (a tracker export often holds reference points, a log rows the beam
missed): :class:`ImportSummary` lists them by line; the campaign's comments say how many. Nothing matched is
refused. Every refusal is one line naming the file and line (bad numbers, duplicate names, unknown units,
missing columns, no match). The campaign is written in the log's row order (the robot's sequence: the
direction rule of formats.md follows it), never over an input file, its comments naming both sources with
their sha256.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import List, Optional

import numpy as np

from olti_drake.errors import InputError

#: mm per unit of the export's lengths.
UNITS = {"mm": 1.0, "m": 1000.0, "in": 25.4}
_UNIT_NAMES = {"mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
               "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
               "in": "in", "inch": "in", "inches": "in"}
MAP_KEYS = ("name", "x", "y", "z", "time")
DEFAULT_MAP = {k: k for k in MAP_KEYS}
_UNITS_COMMENT = re.compile(r"units?\s*[:=]\s*([A-Za-z]+)", re.IGNORECASE)


@dataclass
class ExportPoints:
    """Points of an export: ``points_mm`` (M, 3), ``names`` (M full names or None), ``times_s`` (M,) or None,
    ``lines`` (M,) file lines, ``units`` and where they came from, ``layout`` ('sa' or 'csv')."""

    source: str
    layout: str
    points_mm: np.ndarray
    names: Optional[List[str]]
    times_s: Optional[np.ndarray]
    lines: np.ndarray
    units: str
    units_from: str


@dataclass
class ImportSummary:
    """What :func:`import_points` wrote: ``matched`` pairs, ``match`` ('name'/'time'), the skipped export lines
    and log lines, the export's layout and units."""

    out: str
    match: str
    matched: int
    skipped_points: List[int] = field(default_factory=list)
    skipped_log: List[int] = field(default_factory=list)
    layout: str = ""
    units: str = ""
    units_from: str = ""
    max_dt_s: float = 0.0


def parse_columns(spec: Optional[str]) -> dict:
    """The column map of ``--columns`` (``name=Point,x=X,...``) over :data:`DEFAULT_MAP`."""
    out = dict(DEFAULT_MAP)
    for item in (spec or "").split(","):
        if not item.strip():
            continue
        key, sep, col = (s.strip() for s in item.partition("="))
        if not sep or not col:
            raise InputError(f"--columns: {item.strip()!r} is not KEY=COLUMN (e.g. name=Point,x=X,y=Y,z=Z)")
        if key not in MAP_KEYS:
            raise InputError(f"--columns: unknown key {key!r} (keys: {', '.join(MAP_KEYS)})")
        out[key] = col
    return out


def unit_name(text: str, where: str) -> str:
    """'mm', 'm' or 'in' of a unit's name; refused naming ``where``."""
    u = _UNIT_NAMES.get(text.strip().lower())
    if u is None:
        raise InputError(f"{where}: unknown units {text.strip()!r} (mm, m or in)")
    return u


def _units(given: Optional[str], header: Optional[tuple], name: str):
    """(units, where from): ``--units`` if given (a header that disagrees refused), else the header's, else mm."""
    if header and given and unit_name(given, "--units") != header[0]:
        raise InputError(f"{name}:{header[1]}: the export says units {header[0]}, --units says {given}; drop "
                         f"--units or correct it")
    if given:
        return unit_name(given, "--units"), "--units"
    if header:
        return header[0], f"the export's header (line {header[1]})"
    return "mm", "the default (no units stated)"


def _number(raw: str, name: str, line: int, what: str) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise InputError(f"{name}:{line}: {what}: {repr(raw) if raw else 'missing value'} is not a number") \
            from None
    if not np.isfinite(v):
        raise InputError(f"{name}:{line}: {what}: {raw!r} is not a finite number")
    return v


def parse_time(raw: str, name: str, line: int, what: str) -> float:
    """Seconds of a time field: a number of seconds, or an ISO 8601 timestamp (POSIX seconds; UTC if no zone)."""
    try:
        return _number(raw, name, line, what)
    except InputError:
        pass
    try:
        t = datetime.fromisoformat(raw.strip())
    except ValueError:
        raise InputError(f"{name}:{line}: {what}: {raw!r} is neither seconds nor an ISO 8601 time") from None
    return (t if t.tzinfo else t.replace(tzinfo=timezone.utc)).timestamp()


def _data_lines(path, comment=("#",)):
    from olti_drake.io.csvio import read_text

    return [(i + 1, t) for i, t in enumerate(read_text(path, "tracker export").splitlines())
            if t.strip() and not t.lstrip().startswith(comment)]


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _sa_fields(text: str) -> list:
    return [f for f in re.split(r"[,\s]+", text.strip()) if f]


def read_sa_export(path, units: Optional[str] = None) -> ExportPoints:
    """The points of a SpatialAnalyzer-style ASCII export (module docstring), mm."""
    from olti_drake.io.csvio import read_text

    name = os.fspath(path)
    header = None
    for i, text in enumerate(read_text(path, "tracker export").splitlines()):
        s = text.strip()
        if s.startswith(("//", "#")):
            m = _UNITS_COMMENT.search(s)
            if m and header is None:
                header = (unit_name(m.group(1), f"{name}:{i + 1}"), i + 1)
    u, units_from = _units(units, header, name)
    names, pts, lines = [], [], []
    for line, text in _data_lines(path, ("#", "//")):
        fields = _sa_fields(text)
        if len(fields) < 4:
            raise InputError(f"{name}:{line}: expected a point name and X Y Z, got {len(fields)} field(s)")
        pts.append([_number(f, name, line, axis) for f, axis in zip(fields[-3:], "XYZ")])
        names.append("::".join(p for f in fields[:-3] for p in f.split("::") if p))
        lines.append(line)
    if not lines:
        raise InputError(f"{name}: no points (every line is blank or a comment)")
    return ExportPoints(name, "sa", np.array(pts) * UNITS[u], names, None, np.array(lines), u, units_from)


def read_csv_export(path, columns: Optional[dict] = None, units: Optional[str] = None) -> ExportPoints:
    """The points of a generic column-mapped CSV export (module docstring), mm."""
    name = os.fspath(path)
    cmap = columns or dict(DEFAULT_MAP)
    rows = _data_lines(path)
    if not rows:
        raise InputError(f"{name}: empty file (no header row)")
    (hline, htext), data = rows[0], rows[1:]
    delim = next((d for d in (",", ";", "\t") if d in htext), ",")
    cols = [c.strip() for c in next(csv.reader([htext], delimiter=delim))]
    for key in ("x", "y", "z"):
        if cmap[key] not in cols:
            raise InputError(f"{name}:{hline}: missing column '{cmap[key]}' ({key} of --columns; header has "
                             f"{', '.join(cols)})")
    if not data:
        raise InputError(f"{name}: empty file (no data rows)")
    idx = {k: cols.index(c) for k, c in cmap.items() if c in cols}
    u, units_from = _units(units, None, name)
    pts, names, times, lines = [], [], [], []
    for line, text in data:
        f = [v.strip() for v in next(csv.reader([text], delimiter=delim))]
        if len(f) != len(cols):
            raise InputError(f"{name}:{line}: expected {len(cols)} fields as in the header, got {len(f)}")
        pts.append([_number(f[idx[k]], name, line, f"column '{cmap[k]}'") for k in "xyz"])
        if "name" in idx:
            names.append(f[idx["name"]])
        if "time" in idx:
            times.append(parse_time(f[idx["time"]], name, line, f"column '{cmap['time']}'"))
        lines.append(line)
    return ExportPoints(name, "csv", np.array(pts) * UNITS[u], names if "name" in idx else None,
                        np.array(times) if "time" in idx else None, np.array(lines), u, units_from)


def detect_layout(path) -> str:
    """'sa' when the first data line ends in three numbers (a headerless point list), else 'csv'."""
    rows = _data_lines(path, ("#", "//"))
    fields = _sa_fields(rows[0][1]) if rows else []
    return "sa" if len(fields) >= 4 and all(_is_number(f) for f in fields[-3:]) else "csv"


def read_export(path, layout: str = "auto", columns: Optional[dict] = None,
                units: Optional[str] = None) -> ExportPoints:
    """The points of a tracker export in ``layout`` ('auto', 'csv' or 'sa'), names checked unique."""
    layout = detect_layout(path) if layout == "auto" else layout
    pts = read_sa_export(path, units) if layout == "sa" else read_csv_export(path, columns, units)
    if pts.names is not None:
        _check_unique(pts.names, pts.lines, pts.source, "point name")
    return pts


def _check_unique(names, lines, source, what) -> None:
    first = {}
    for n, line in zip(names, lines):
        if not n:
            raise InputError(f"{source}:{line}: empty {what}")
        if n in first:
            raise InputError(f"{source}:{line}: duplicate {what} {n!r} (first on line {first[n]})")
        first[n] = line


@dataclass
class JointLog:
    """The robot's joint log: its :class:`~olti_drake.io.serial_io.JointTable`, names (or None), times_s (or
    None)."""

    joints: object
    names: Optional[List[str]]
    times_s: Optional[np.ndarray]


def read_joint_log(path) -> JointLog:
    """The joint log of the module docstring; names checked unique."""
    from olti_drake.io.csvio import check_values
    from olti_drake.io.serial_io import header, read_joint_table

    name = os.fspath(path)
    jt = read_joint_table(path, optional=("valid",))
    if "valid" in jt.table:
        check_values(jt.table, path, "valid", (0.0, 1.0))
    hline, cols = header(path)
    text_cols = [c for c in ("name", "point", "timestamp", "time_s") if c in cols]
    fields = {}
    if text_cols:
        rows = _data_lines(path)[1:]
        by_line = {line: [f.strip() for f in next(csv.reader([t]))] for line, t in rows}
        fields = {c: [by_line[int(line)][cols.index(c)] for line in jt.line] for c in text_cols}
    key = next((c for c in ("name", "point") if c in fields), None)
    names = fields[key] if key else None
    if names is not None:
        _check_unique(names, jt.line, name, f"'{key}'")
    tcol = next((c for c in ("time_s", "timestamp") if c in fields), None)
    times = None if tcol is None else np.array([parse_time(v, name, int(line), f"column '{tcol}'")
                                                for v, line in zip(fields[tcol], jt.line)])
    return JointLog(jt, names, times)


def match_by_name(points: ExportPoints, log: JointLog):
    """(point index, log index) pairs of the exact name match (module docstring), log order."""
    full = {n: i for i, n in enumerate(points.names)}
    target = {}
    for i, n in enumerate(points.names):
        target.setdefault(n.split("::")[-1], []).append(i)
    pairs = []
    for j, n in enumerate(log.names):
        i = full.get(n, target[n][0] if len(target.get(n, ())) == 1 else None)
        if i is not None:
            pairs.append((i, j))
    return pairs


def match_by_time(points: ExportPoints, log: JointLog, max_dt_s: float):
    """(point index, log index) pairs within ``max_dt_s``, closest first, each used at most once."""
    order = np.argsort(log.times_s, kind="stable")
    t_log = log.times_s[order]
    cand = []
    for i, t in enumerate(points.times_s):
        lo, hi = np.searchsorted(t_log, t - max_dt_s, "left"), np.searchsorted(t_log, t + max_dt_s, "right")
        for k in range(lo, hi):
            cand.append((abs(t_log[k] - t), t, t_log[k], i, int(order[k])))
    used_p, used_l, pairs = set(), set(), []
    for _, _, _, i, j in sorted(cand):  # (ties broken by the times themselves, not by row order)
        if i not in used_p and j not in used_l:
            used_p.add(i)
            used_l.add(j)
            pairs.append((i, j))
    return pairs


def import_points(export, joint_log, out, *, layout: str = "auto", columns: Optional[str] = None,
                  units: Optional[str] = None, match: Optional[str] = None, max_dt_s: float = 0.5) -> ImportSummary:
    """Read ``export`` and ``joint_log``, match them (``match`` 'name', 'time' or None: by name when both have
    names, else by time) and write the point campaign ``out`` (module docstring)."""
    from olti_drake.io.five_axis_io import file_sha256
    from olti_drake.io.serial_io import write_serial_campaign

    points = read_export(export, layout, parse_columns(columns), units)
    log = read_joint_log(joint_log)
    match = match or ("name" if points.names is not None and log.names is not None else "time")
    need = {"name": ("names", "a point name (SA names, or name= of --columns)", "a 'name' or 'point' column"),
            "time": ("times_s", "a time column (time= of --columns)", "a 'time_s' or 'timestamp' column")}[match]
    for obj, src, what in ((points, points.source, need[1]), (log, os.fspath(joint_log), need[2])):
        if getattr(obj, need[0]) is None:
            raise InputError(f"{src}: matching by {match} needs {what}")
    if match == "time" and not max_dt_s > 0:
        raise InputError(f"--max-dt-s: {max_dt_s} is not a positive number of seconds")
    pairs = match_by_name(points, log) if match == "name" else match_by_time(points, log, max_dt_s)
    if not pairs:
        hint = (f" within {max_dt_s:g} s (a larger --max-dt-s, or clocks on one time base?)" if match == "time" else
                f" (the export's names e.g. {points.names[0]!r}, the log's e.g. {log.names[0]!r}; --match time "
                f"matches by time stamps)")
        raise InputError(f"{points.source}: no point matches a row of {os.fspath(joint_log)} by {match}{hint}")
    pairs.sort(key=lambda p: p[1])
    pi, lj = (np.array(v, int) for v in zip(*pairs))
    jt = log.joints
    summary = ImportSummary(os.fspath(out), match, len(pairs),
                            sorted(int(v) for v in np.delete(points.lines, pi)),
                            sorted(int(v) for v in np.delete(jt.line, lj)), points.layout, points.units,
                            points.units_from, max_dt_s)
    how = f"by {match}" + (f" (nearest within {max_dt_s:g} s)" if match == "time" else " (exact)")
    write_serial_campaign(out, jt.commands[lj], None if jt.dirs is None else jt.dirs[lj],
                          points_mm=points.points_mm[pi],
                          valid=jt.table["valid"][lj] if "valid" in jt.table else None, comments=[
        f"olti import-points: tracker points of {points.source} (sha256 {file_sha256(points.source)}; "
        f"{'SpatialAnalyzer-style ASCII' if points.layout == 'sa' else 'CSV'} export, units {points.units} from "
        f"{points.units_from}, converted to mm; x_mm, y_mm, z_mm in the tracker frame)",
        f"joint commands of {os.fspath(joint_log)} (sha256 {file_sha256(joint_log)}), its row order",
        f"matched {how}: {len(pairs)} rows; skipped {len(summary.skipped_points)} export point(s) and "
        f"{len(summary.skipped_log)} log row(s) without a match"])
    return summary
