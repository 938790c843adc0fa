"""Files of N-joint serial robots (formats.md, "Serial robots with N joints, in 3D"): campaigns,
commands and targets, results and truths, and the robot model a file names.

* :func:`read_serial_campaign` — a distance campaign (``station`` or its synonym ``reflector``,
  ``theta1_deg`` … ``thetaN_deg``, optional ``dir1`` … ``dirN``, ``displacement_mm``, optional
  ``valid``) or a point campaign (``x_mm, y_mm, z_mm`` measured by a tracker); every bad file is
  one line naming the file, the line and the column (csvio's checks: numbers, finite values,
  unit bounds, duplicate rows, directions ±1, the number of joint columns against the robot's N,
  a station with too few readings).
* :func:`read_joint_table` — the same joint columns in a commands or targets file.
* :func:`write_serial_campaign` — a campaign written as a measurement (never replaced).
* :func:`serial_result_dict` / :func:`write_serial_result` / :func:`load_serial_result` — the
  ``olti-result/1`` result of a serial robot; the loader rebuilds the
  :class:`~olti_drake.model.serial.SerialPositionModel` (the chain from ``robot.file``, relative to
  the result file, or a shipped model name) so predict and compensate evaluate it. The result also stores the
  identification's parameter covariance (``covariance``: ``names`` and the packed ``lower`` triangle,
  :func:`covariance_entry`; not stored above :data:`MAX_COVARIANCE_PARAMETERS`), the smoothness prior it had
  (``smoothing``) and, when the program is given, its ``--regularize`` priors (``priors``, :func:`program_priors`);
  a result without ``covariance`` (older versions) loads, and its predictions carry no u. A truth
  (:func:`serial_truth_dict`: every location error by name, maps sampled on a fine grid) loads the
  same way.

Units: mm and degrees in every file (the chain converts to SI at Drake's ports only).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import ROBOT_RESULT as FORMAT
from olti_drake.io import documents
from olti_drake.io.documents import result_kind
from olti_drake.io.csvio import (check_finite, check_no_duplicate_rows, check_values, data_digest, json_numbers,
                                 read_json, read_table, read_text, write_table)
from olti_drake.io.resources import PACKAGE_DIR

#: Robot models shipped with the package, by the name ``--robot`` and ``robot.file`` accept.
SHIPPED_ROBOTS = {"ur5": "ur5.urdf", "scara": "scara.sdf"}
#: A station's own unknowns (x, y, z, dead path) take 4 readings before one says anything about the robot.
MIN_STATION_READINGS = 5
POINT_COLUMNS = ("x_mm", "y_mm", "z_mm")
CAMPAIGN_FORMATS = {"station": "%d", "displacement_mm": "%.9f", "x_mm": "%.9f", "y_mm": "%.9f",
                    "z_mm": "%.9f", "valid": "%d"}


def theta_columns(n: int):
    return tuple(f"theta{i}_deg" for i in range(1, n + 1))


def dir_columns(n: int):
    return tuple(f"dir{i}" for i in range(1, n + 1))


# ---------------------------------------------------------------------- robot
def resolve_robot(spec, relative_to=None) -> Path:
    """The model file a ``--robot`` value or a result's ``robot.file`` names: a shipped model
    (:data:`SHIPPED_ROBOTS`), else a path (a relative one taken from ``relative_to``, a folder)."""
    spec = os.fspath(spec)
    if spec.lower() in SHIPPED_ROBOTS:
        return PACKAGE_DIR / "models" / SHIPPED_ROBOTS[spec.lower()]
    path = Path(spec)
    if relative_to is not None and not path.is_absolute():
        path = Path(relative_to) / path
    return path


def load_robot(spec, tool_frame: str, relative_to=None):
    """The :class:`~olti_drake.model.chain.SerialChain` of a robot model to ``tool_frame`` (one-line errors
    name the file and the frame or joint; see ``load_serial_chain``)."""
    from olti_drake.model.chain import load_serial_chain

    if not tool_frame:
        raise InputError(f"robot model {spec}: the tool frame is missing (give --tool-frame NAME)")
    return load_serial_chain(resolve_robot(spec, relative_to), tool_frame)


def robot_reference(spec, result_path) -> str:
    """What a result stores as ``robot.file``: a shipped name as given, else the path relative to the
    result file's folder (so the pair can move together), absolute when on another drive."""
    spec = os.fspath(spec)
    if spec.lower() in SHIPPED_ROBOTS:
        return spec.lower()
    try:
        return os.path.relpath(os.path.abspath(spec), os.path.dirname(os.path.abspath(result_path)))
    except ValueError:
        return os.path.abspath(spec)


def robot_digest(path) -> str:
    """sha256 (hex) of a robot model file's bytes: a result stores it as ``robot.sha256`` (the model its
    parameters are errors of), and a file edited since is refused by name (:func:`check_robot_digest`)."""
    import hashlib

    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


_UNCHECKED_NOTED = set()


def check_robot_digest(data: dict, name: str, robot_path) -> None:
    """Refuse a robot model file that is not the one the result ``name`` was identified with (its
    ``robot.sha256``), one line naming both; a result written before the digest existed loads, with a one-line
    note (stderr, once per file)."""
    stored = (data.get("robot") or {}).get("sha256")
    if stored is None:
        if name not in _UNCHECKED_NOTED:
            _UNCHECKED_NOTED.add(name)
            import sys

            print(f"note: {name} carries no digest of its robot model file (written by an older version): not "
                  f"checked that {os.fspath(robot_path)} is unchanged", file=sys.stderr, flush=True)
        return
    here = robot_digest(robot_path)
    if stored != here:
        raise InputError(f"{name}: the robot model file {os.fspath(robot_path)} changed since the identification "
                         f"(sha256 {here[:12]}..., the result's robot.sha256 {str(stored)[:12]}...): its parameters "
                         f"are errors of the model as it was; identify again")


# ------------------------------------------------------------------ campaigns
@dataclass(frozen=True)
class JointTable:
    """Joint columns of a file: commands (M, N) deg, dirs (M, N) ±1 or None, the checked table
    (column -> values, ``_line``: file lines), the file name."""

    commands: np.ndarray
    dirs: Optional[np.ndarray]
    table: Dict[str, np.ndarray]
    source: str

    @property
    def line(self) -> np.ndarray:
        return self.table["_line"]

    @property
    def n_joints(self) -> int:
        return self.commands.shape[1]


def header(path):
    """(1-based line, column names) of a CSV file's header row (comments and blank lines skipped)."""
    for i, text in enumerate(read_text(path).splitlines()):
        if text.strip() and not text.lstrip().startswith("#"):
            return i + 1, [c.strip() for c in next(csv.reader([text]))]
    raise InputError(f"{os.fspath(path)}: empty file (no header row)")


#: The SCARA campaign's optional column of the commanded J4 angle that steered the beam (000 Eq. (1), formats.md):
#: every SCARA file stays a valid N = 2 campaign of the chain J1, J2 (``models/scara.sdf`` to ``beam``).
SCARA_STEERING_COLUMN = "theta4_deg"


def joint_count(path, n_joints: Optional[int] = None, robot: str = "") -> int:
    """N of a file's ``theta1_deg`` … ``thetaN_deg`` columns (consecutive from 1), checked against the
    robot's ``n_joints`` when given: one line naming the file, its header line and the robot."""
    name = os.fspath(path)
    line, cols = header(path)
    found = sorted(int(c[5:-4]) for c in cols if c.startswith("theta") and c.endswith("_deg") and c[5:-4].isdigit())
    n = 0
    while n + 1 in found:
        n += 1
    if n == 0:
        raise InputError(f"{name}:{line}: missing required column 'theta1_deg' (joint angles theta1_deg .. "
                         f"thetaN_deg; header has {', '.join(cols)})")
    stray = [f"theta{k}_deg" for k in found if k > n]
    if n == 2 and stray == [SCARA_STEERING_COLUMN]:
        stray = []  # a SCARA campaign's J4 steering command (formats.md): not a joint of the position chain
    if stray:
        raise InputError(f"{name}:{line}: column '{stray[0]}' without 'theta{n + 1}_deg': joint columns run "
                         f"theta1_deg .. thetaN_deg without a gap")
    if n_joints is not None and n != n_joints:
        who = f"the robot {robot}" if robot else "the robot"
        raise InputError(f"{name}:{line}: {n} joint columns (theta1_deg .. theta{n}_deg) but {who} has "
                         f"{n_joints} joints on its chain")
    return n


def read_joint_table(path, n_joints: Optional[int] = None, required: Sequence[str] = (),
                     optional: Sequence[str] = (), integer: Sequence[str] = (), robot: str = "",
                     valid_only: bool = False) -> JointTable:
    """The joint columns (and ``required`` / ``optional`` others) of a CSV file, checked.

    Direction columns are optional but come all or none; they must be ±1. ``valid_only``: rows
    with ``valid`` = 0 are dropped (the file keeps them; counted in ``table['_skipped']``).
    Checks, each one line naming file, line and column: the joint count, numbers, finite values
    within the unit bounds (olti_drake.units.UNIT_BOUNDS), a row identical to an earlier one.
    """
    name = os.fspath(path)
    n = joint_count(path, n_joints, robot)
    thetas, dirs = theta_columns(n), dir_columns(n)
    line, cols = header(path)
    present = [d for d in dirs if d in cols]
    if present and len(present) != n:
        missing = next(d for d in dirs if d not in cols)
        raise InputError(f"{name}:{line}: missing column '{missing}': direction columns dir1 .. dir{n} come "
                         f"all together or not at all")
    opt = list(optional) + (["valid"] if valid_only else []) + list(present)
    t = read_table(path, list(thetas) + list(required), opt, integer=list(integer) + present
                   + (["valid"] if valid_only else []))
    skipped = 0
    if valid_only and "valid" in t:
        check_values(t, path, "valid", (0.0, 1.0))
        keep = t["valid"] == 1
        if not keep.any():
            raise InputError(f"{name}: no valid readings (every row has valid = 0)")
        skipped = int((~keep).sum())
        t = {k: v[keep] for k, v in t.items()}
    check_no_duplicate_rows(t, path)
    check_finite(t, path, list(thetas) + [c for c in list(required) + list(optional) if c in t])
    for d in present:
        check_values(t, path, d, (-1.0, 1.0))
    t["_skipped"] = skipped
    commands = np.column_stack([t[c] for c in thetas])
    return JointTable(commands, np.column_stack([t[d] for d in dirs]) if present else None, t, name)


@dataclass(frozen=True)
class SerialCampaign:
    """The valid readings of an N-joint campaign (formats.md): ``kind`` 'distance' (``station`` labels,
    ``displacement_mm``) or 'point' (``points_mm`` (M, 3) in the tracker frame); commands (M, N) deg,
    dirs (M, N) ±1 or None (one-directional), the file lines, rows skipped as ``valid`` = 0."""

    kind: str
    commands: np.ndarray
    dirs: Optional[np.ndarray]
    line: np.ndarray
    source: str
    station: Optional[np.ndarray] = None
    displacement_mm: Optional[np.ndarray] = None
    points_mm: Optional[np.ndarray] = None
    n_skipped: int = 0
    #: ``time_s`` (optional column): seconds since any origin, for the dead-path drift (``--drift``).
    time_s: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.commands)

    @property
    def n_joints(self) -> int:
        return self.commands.shape[1]

    def subset(self, rows) -> "SerialCampaign":
        pick = (lambda a: None if a is None else a[rows])
        return SerialCampaign(self.kind, self.commands[rows], pick(self.dirs), self.line[rows], self.source,
                              pick(self.station), pick(self.displacement_mm), pick(self.points_mm), self.n_skipped,
                              pick(self.time_s))

    def digest(self) -> dict:
        """{"readings", "sha256"} of the valid readings (csvio.data_digest), as the SCARA results'."""
        cols = [self.commands[:, i] for i in range(self.n_joints)]
        cols += [] if self.dirs is None else [self.dirs[:, i] for i in range(self.n_joints)]
        if self.kind == "distance":
            return data_digest(self.station, *cols, self.displacement_mm)
        return data_digest(*cols, *self.points_mm.T)


def campaign_kind(path) -> str:
    """'distance' when the file has ``displacement_mm``, else 'point' when it has x_mm, y_mm, z_mm."""
    line, cols = header(path)
    if "displacement_mm" in cols:
        return "distance"
    if all(c in cols for c in POINT_COLUMNS):
        return "point"
    raise InputError(f"{os.fspath(path)}:{line}: missing required column 'displacement_mm' (a distance "
                     f"campaign) or 'x_mm', 'y_mm', 'z_mm' (a point campaign); header has {', '.join(cols)}")


def station_column(path) -> str:
    """'station', or its synonym 'reflector' (not both)."""
    line, cols = header(path)
    if "station" in cols and "reflector" in cols:
        raise InputError(f"{os.fspath(path)}:{line}: both 'station' and 'reflector' columns: they are synonyms, "
                         f"keep one")
    return "reflector" if "reflector" in cols else "station"


def read_serial_campaign(path, n_joints: Optional[int] = None, robot: str = "") -> SerialCampaign:
    """Read a distance or point campaign of an N-joint robot (formats.md); skip ``valid`` = 0 rows.

    ``n_joints``: the robot's joint count the file's ``theta`` columns must match. Distance
    campaigns: station labels whole numbers >= 0, each with at least :data:`MIN_STATION_READINGS`
    valid readings. One-line errors name the file, line and column (or station)."""
    name = os.fspath(path)
    kind = campaign_kind(path)
    if kind == "point":
        jt = read_joint_table(path, n_joints, POINT_COLUMNS, robot=robot, valid_only=True)
        t = jt.table
        return SerialCampaign("point", jt.commands, jt.dirs, jt.line, name,
                              points_mm=np.column_stack([t[c] for c in POINT_COLUMNS]), n_skipped=t["_skipped"])
    col = station_column(path)
    jt = read_joint_table(path, n_joints, (col, "displacement_mm"), ("time_s",), integer=(col,), robot=robot,
                          valid_only=True)
    t = jt.table
    station = t[col]
    bad = np.flatnonzero(station < 0)
    if bad.size:
        raise InputError(f"{name}:{t['_line'][bad[0]]}: column '{col}': {station[bad[0]]:g} is not an index >= 0")
    station = station.astype(int)
    labels, counts = np.unique(station, return_counts=True)
    few = np.flatnonzero(counts < MIN_STATION_READINGS)
    if few.size:
        j = labels[few[0]]
        raise InputError(f"{name}: {col} {j} has {counts[few[0]]} valid reading(s) (first on line "
                         f"{t['_line'][np.flatnonzero(station == j)[0]]}); a station needs at least "
                         f"{MIN_STATION_READINGS}: its position (x, y, z) and dead path take 4 before one says "
                         f"anything about the robot")
    return SerialCampaign("distance", jt.commands, jt.dirs, jt.line, name, station=station,
                          displacement_mm=t["displacement_mm"], n_skipped=t["_skipped"], time_s=t.get("time_s"))


def write_serial_campaign(path, commands, dirs=None, *, station=None, displacement_mm=None, points_mm=None,
                          valid=None, comments: Sequence[str] = (), extra: Optional[Dict[str, Sequence]] = None,
                          formats: Optional[Dict[str, str]] = None) -> str:
    """Write an N-joint campaign (formats.md) as a measurement: never replacing a file, atomically.

    A distance campaign has ``station`` and ``displacement_mm``, a point campaign ``points_mm``
    (M, 3). ``commands`` (M, N) deg, ``dirs`` (M, N) ±1 or None (no direction columns), ``valid``
    (M,) 1/0 or None. ``extra``: more columns after these (e.g. a run's step), with ``formats``.
    Same data, same bytes (deterministic formats)."""
    commands = np.atleast_2d(np.asarray(commands, float))
    m, n = commands.shape
    cols: Dict[str, Sequence] = {}
    if (station is None) == (points_mm is None) or (station is None) != (displacement_mm is None):
        raise ValueError("write_serial_campaign: give station + displacement_mm (distance) or points_mm (point)")
    if station is not None:
        cols["station"] = np.asarray(station, int).reshape(m)
    for i, c in enumerate(theta_columns(n)):
        cols[c] = commands[:, i]
    if dirs is not None:
        d = np.broadcast_to(np.asarray(dirs, float), commands.shape)
        for i, c in enumerate(dir_columns(n)):
            cols[c] = d[:, i].astype(int)
    if station is not None:
        cols["displacement_mm"] = np.asarray(displacement_mm, float).reshape(m)
    else:
        pts = np.asarray(points_mm, float).reshape(m, 3)
        for i, c in enumerate(POINT_COLUMNS):
            cols[c] = pts[:, i]
    if valid is not None:
        cols["valid"] = np.asarray(valid, int).reshape(m)
    for k, v in (extra or {}).items():
        cols[k] = v
    fmt = dict(CAMPAIGN_FORMATS)
    fmt.update({c: "%.12g" for c in theta_columns(n)})
    fmt.update({c: "%d" for c in dir_columns(n)})
    fmt.update(formats or {})
    write_table(path, cols, fmt, comments=list(comments) + ["mm and degrees (formats.md, serial robots)"],
                measurement=True)
    return os.fspath(path)


# -------------------------------------------------------------------- results
def serial_result_dict(*, kind: str, robot_file: str, measurement, fit, gauge: str, campaign_digest: dict = None,
                       notes: Sequence[str] = (), extra: Optional[dict] = None, program=None) -> dict:
    """The ``result.json`` object of an identified serial robot (formats.md).

    ``measurement``: the :class:`~olti_drake.model.serial.DistanceMeasurement` or ``PointMeasurement``
    identified (its model gives ``robot.joints``, the location errors and offsets by name,
    ``tool_offset_mm``, ``error_map`` keyed by joint name, and ``dropped``); ``fit``: the
    least-squares fit (x, std, residuals, …). ``held_location_errors_mm_deg``: the location errors not
    identified (held at these values, zero unless a start said otherwise). ``program``: the identification
    program (its quadratic costs: the ``--regularize`` priors, recorded under ``priors``; optional).

    Also written: ``covariance`` (:func:`covariance_entry`: the fit's parameter covariance, for the u of
    ``olti predict``), ``smoothing`` (the fit's roughness prior, when it had one). The common fields (gauge,
    residual RMS, readings, uncertainty with k and method, the fit's facts, campaign, notes) are written by the one
    codec, :func:`olti_drake.io.documents.result_document`; this adds the serial robot's own.
    """
    model = measurement.model
    chain = model.chain
    x = np.asarray(fit.x, float)
    out = {"model": kind,
           "robot": {"file": robot_file, "tool_frame": chain.tool_frame, "joints": list(chain.joint_names)}}
    if os.path.isfile(getattr(chain, "path", "") or ""):  # the model file the parameters are errors of
        out["robot"]["sha256"] = robot_digest(chain.path)
    out.update(measurement.layout(x))
    if hasattr(measurement, "labels"):  # the campaign's station index of each row of stations_mm
        out["station_labels"] = [int(j) for j in measurement.labels]
    if getattr(measurement, "time_h", None) is not None:  # the drift's time origin per station (not a parameter)
        out["drift_reference_h"] = measurement.drift_reference_h.tolist()
    held = {name: float(v) for name, v in zip(chain.parameter_names(), model.chain_params)
            if name not in model.names and name not in ("tool_x_mm", "tool_y_mm", "tool_z_mm") and v != 0.0}
    if held:
        out["held"] = held
    unc = measurement.layout(np.asarray(fit.std, float), uncertainty=True)
    for m in unc.get("error_map", {}).values():
        m.pop("grid_deg", None)
    if "tracker_frame" in unc:
        unc["tracker_frame"].pop("convention", None)
    tail = covariance_entry(fit)  # the serial robot's own, after the common fields
    priors = program_priors(program) if program is not None else []
    if priors:
        tail["priors"] = priors
    tail["dropped"] = [{"parameter": p, "reason": why} for p, why in model.dropped]
    tail.update(extra or {})
    return documents.result_document("serial", out, fit, gauge=gauge, uncertainty=unc,
                                     n_readings=len(measurement.commands), campaign=campaign_digest, notes=notes,
                                     tail=tail)


#: The most parameters whose covariance a result stores (N (N + 1) / 2 numbers: 1000 -> 0.5 M, ~14 MB of JSON);
#: above, the result says so under ``covariance.omitted`` and its predictions carry no u.
MAX_COVARIANCE_PARAMETERS = 1000


def covariance_entry(fit) -> dict:
    """``{"covariance": ...}`` of a result (formats.md, serial robots; empty when the fit has none): the
    covariance C (k = 1, the parameters' units squared: mm², deg², mm·deg) of ``fit.names`` -- the model's
    parameters, then the stations' and dead paths' or the tracker frame's -- as ``names`` and ``lower``, the
    lower triangle packed row by row (C[0,0], C[1,0], C[1,1], C[2,0], ...: N (N + 1) / 2 numbers). It is the
    identification's own (readings' variance from the residual, priors included), the one the result's
    ``uncertainty`` holds the square roots of the diagonal of; ``olti predict`` propagates it
    (model.propagation). Above :data:`MAX_COVARIANCE_PARAMETERS` it is not stored: ``{"names": [...],
    "omitted": reason}``."""
    names = list(getattr(fit, "names", []) or [])
    if not names:
        return {}
    if len(names) > MAX_COVARIANCE_PARAMETERS:
        return {"covariance": {"names": names, "omitted": (
            f"{len(names)} parameters: the covariance would take {len(names) * (len(names) + 1) // 2} numbers "
            f"(more than {MAX_COVARIANCE_PARAMETERS} parameters are not stored); predictions carry no u")}}
    C = getattr(fit, "covariance", None)
    if C is None:
        return {}
    C = np.asarray(C, float)
    if C.shape != (len(names), len(names)) or not np.all(np.isfinite(C)):
        return {}
    C = 0.5 * (C + C.T)
    return {"covariance": {"names": names, "lower": C[np.tril_indices(len(names))].tolist(), "k": 1,
                           "packing": "lower triangle row by row: C[0,0], C[1,0], C[1,1], C[2,0], ...",
                           "lack_of_fit_mm": float(getattr(fit, "lack_of_fit_mm", 0.0) or 0.0)}}


def program_priors(program) -> list:
    """The diagonal quadratic costs of an identification program (the ``--regularize`` priors ½ w (x − x0)²,
    :func:`olti_drake.estimation.serial_identification.prior_weight`) as the result's ``priors``:
    ``[{"kind": "regularize", "names": [...], "weights": [...]}]`` (weights in the data cost's units: mm² per
    unit² of the parameter). The smoothness prior is not among them: the result states it as ``smoothing``
    (its weight; the roughness rows follow from the maps)."""
    from pydrake.solvers import QuadraticCost

    names, weights = [], []
    costs = getattr(program, "_user_costs", None)
    for b in (costs() if costs is not None else []):
        e = b.evaluator()
        if not isinstance(e, QuadraticCost) or "smoothness" in (e.get_description() or ""):
            continue
        Q = np.asarray(e.Q(), float)
        if np.any(Q - np.diag(np.diag(Q))):
            continue  # (not a prior on single parameters: no such cost is written by olti identify)
        for v, w in zip(b.variables(), np.diag(Q)):
            if w > 0:
                names.append(v.get_name())
                weights.append(float(w))
    return [{"kind": "regularize", "names": names, "weights": weights}] if names else []


def write_serial_result(path, result: dict) -> None:
    from olti_drake.io.outputs import write_json

    write_json(path, result)


def serial_truth_dict(truth, robot_file: str, *, grid_step_deg: float = 0.25, ranges_deg=None) -> dict:
    """A simulation truth in the result format: every location error of the chain by name, the tool
    offset, error maps sampled every ``grid_step_deg`` over ``ranges_deg`` (N, 2) (default the joint
    limits, ±180° where unlimited; both approach directions), the stations, dead paths and tracker
    frame; ``"truth": true``. :func:`load_serial_result` reads it as a model like any other."""
    from olti_drake.model.chain import UNLIMITED_RANGE_DEG
    from olti_drake.model.serial import grid_every

    chain = truth.chain
    if ranges_deg is None:
        lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -UNLIMITED_RANGE_DEG)
        hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, UNLIMITED_RANGE_DEG)
        ranges_deg = np.column_stack([lo, hi])
    out = {"format": FORMAT, "model": "errormap", "truth": True,
           "robot": {"file": robot_file, "tool_frame": chain.tool_frame, "joints": list(chain.joint_names)}}
    if os.path.isfile(getattr(chain, "path", "") or ""):
        out["robot"]["sha256"] = robot_digest(chain.path)
    n = chain.n_joints
    for name, v in zip(chain.parameter_names()[:6 * n], truth.chain_params[:6 * n]):
        out[name] = float(v)
    out["tool_offset_mm"] = np.asarray(truth.chain_params[6 * n:], float).tolist()
    maps = {}
    for joint, dev, (lo, hi) in zip(chain.joint_names, truth.deviations, np.asarray(ranges_deg, float)):
        g = grid_every(grid_step_deg, lo, hi)
        maps[joint] = {"grid_deg": g.tolist(), "forward_deg": dev(g, 1.0).tolist(),
                       "reverse_deg": dev(g, -1.0).tolist()}
    out["error_map"] = maps
    out["stations_mm"] = np.asarray(truth.stations_mm, float).tolist()
    out["dead_paths_mm"] = np.asarray(truth.dead_paths_mm, float).tolist()
    f = np.asarray(truth.frame, float)
    out["tracker_frame"] = {"translation_mm": f[:3].tolist(), "rotation_deg": f[3:].tolist(),
                            "convention": "tracker point = R p + t, R = Rx(rx) Ry(ry) Rz(rz)"}
    out["gauge"] = "simulation truth: the root frame of the model"
    return out


def lack_of_fit_of(document: dict) -> float:
    """A result document's ``covariance.lack_of_fit_mm`` (mm, k = 1; 0 when absent), checked: a number >= 0,
    else one line naming the key (every result kind that states one: serial robots, five-axis machines)."""
    entry = document.get("covariance")
    return checked_lack_of_fit(entry.get("lack_of_fit_mm", 0.0) if isinstance(entry, dict) else 0.0,
                               "covariance.lack_of_fit_mm")


def checked_lack_of_fit(value, key: str) -> float:
    """A result's stated lack of fit ``value`` (mm, k = 1) as a float: a number >= 0, else one line naming the
    ``key`` it was read from."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise InputError(f"key '{key}': a number >= 0 (mm), got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)
class SerialResult:
    """A serial robot's result rebuilt: ``model`` (SerialPositionModel, its start vector = the
    identified values), stations (Nt, 3) mm and dead paths, or the tracker frame (6: mm, deg), the
    raw dict, the robot file as resolved."""

    model: object
    stations_mm: Optional[np.ndarray]
    dead_paths_mm: Optional[np.ndarray]
    tracker_frame: Optional[np.ndarray]
    data: dict
    robot_path: str
    #: The identification's parameter covariance (k = 1) and the names of its rows (:func:`covariance_entry`);
    #: None when the result stores none (older versions, a truth, or omitted for its size).
    covariance: Optional[np.ndarray] = None
    covariance_names: Optional[tuple] = None

    @property
    def x(self) -> np.ndarray:
        return self.model.start_vector()

    def covariance_of(self, names) -> Optional[np.ndarray]:
        """The stored covariance over ``names`` (in that order; e.g. a model's and a measurement's), or None when
        the result stores none. A name it does not hold is refused (InputError: the result and the names are of
        different models)."""
        if self.covariance is None:
            return None
        index = {n: i for i, n in enumerate(self.covariance_names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise InputError(f"key 'covariance.names': no row for {missing[0]} (the result's covariance is not "
                             f"of this model)")
        idx = np.array([index[n] for n in names], int)
        return self.covariance[np.ix_(idx, idx)]

    @property
    def lack_of_fit_mm(self) -> float:
        """The fit's model error (mm, k = 1; ``covariance.lack_of_fit_mm``, 0 when absent) that every prediction
        shares, added in quadrature to the u the covariance gives (:meth:`LeastSquaresProgram.lack_of_fit`)."""
        return lack_of_fit_of(self.data)

    @property
    def covariance_note(self) -> str:
        """Why the result's predictions carry no u ("" when they do)."""
        if self.covariance is not None:
            return ""
        entry = self.data.get("covariance")
        if isinstance(entry, dict) and entry.get("omitted"):
            return f"u unavailable: the result stores no covariance ({entry['omitted']})"
        if self.data.get("truth"):
            return "u unavailable: a simulation truth has no covariance"
        return ("u unavailable: the result stores no covariance (written by an older version: identify again for "
                "u_x_mm, u_y_mm, u_z_mm)")

    @property
    def station_labels(self) -> np.ndarray:
        """The campaign's station index of each row of ``stations_mm`` (default 0, 1, ...)."""
        n = 0 if self.stations_mm is None else len(self.stations_mm)
        labels = self.data.get("station_labels")
        return np.arange(n) if labels is None else np.asarray(labels, int)


def load_serial_result(path, outside: str = "error", identified: bool = False) -> SerialResult:
    """Read a serial robot's result.json (or a truth) and rebuild its model.

    The chain is loaded from ``robot.file`` (a shipped name, or a path relative to the result file)
    to ``robot.tool_frame`` and must have the joints ``robot.joints``; location errors and ``dh``
    offsets are read by name, ``tool_offset_mm``, the maps (``forward_deg``, and ``reverse_deg`` for
    a bidirectional map) on their ``grid_deg``, then the stations and dead paths or the tracker
    frame. ``identified``: refuse a truth. Every value is checked where it is read; one-line errors
    name the file and the key."""
    from olti_drake.model.chain import GEOMETRIC_SUFFIXES
    from olti_drake.model.errormap import ErrorMap
    from olti_drake.model.serial import JointMap, SerialPositionModel

    name = os.fspath(path)
    data = read_json(path, FORMAT, "a result (olti identify)")
    kind = result_kind(data, name)
    if kind != "serial":
        raise InputError(f"{name}: key 'kind' is {kind!r}, not a serial robot's result" if "kind" in data else
                         f"{name}: missing key 'robot' (a serial robot's result names its robot file and tool frame)")
    if identified and data.get("truth"):
        raise InputError(f"{name}: a simulation truth, not an identified result (olti identify)")
    kind = data.get("model")
    if kind not in ("dh", "errormap"):
        raise InputError(f"{name}: 'model' must be 'dh' or 'errormap', got {kind!r}")
    robot = data["robot"]
    for key in ("file", "tool_frame"):
        if not isinstance(robot.get(key), str) or not robot.get(key):
            raise InputError(f"{name}: key 'robot.{key}' must be a non-empty string")
    try:
        chain = load_robot(robot["file"], robot["tool_frame"], os.path.dirname(os.path.abspath(name)))
    except ValueError as e:
        raise InputError(f"{name}: robot.file: {e}") from None
    if "sha256" in robot and not isinstance(robot["sha256"], str):
        raise InputError(f"{name}: key 'robot.sha256' must be a string (the robot model file's digest)")
    check_robot_digest(data, name, resolve_robot(robot["file"], os.path.dirname(os.path.abspath(name))))
    joints = robot.get("joints")
    if joints is not None and list(joints) != list(chain.joint_names):
        raise InputError(f"{name}: key 'robot.joints' {list(joints)} is not the chain of {robot['file']} to "
                         f"'{robot['tool_frame']}': {list(chain.joint_names)}")
    n = chain.n_joints
    params = np.zeros(6 * n + 3)
    loc_names = chain.parameter_names()[:6 * n]
    geometric = [k for k in loc_names if k in data]
    for k in geometric:
        params[loc_names.index(k)] = float(json_numbers(data, name, k))
    for k, v in (data.get("held") or {}).items():
        if k not in loc_names:
            raise InputError(f"{name}: key 'held.{k}' is not a location error of the chain "
                             f"(<joint>_{', '.join(GEOMETRIC_SUFFIXES)})")
        params[loc_names.index(k)] = float(json_numbers(data["held"], name, k, label=f"held.{k}"))
    params[6 * n:] = json_numbers(data, name, "tool_offset_mm", (3,))
    offsets = [j for j in chain.joint_names if f"{j}_offset_deg" in data]
    if kind == "dh":
        offset_values = [float(json_numbers(data, name, f"{j}_offset_deg")) for j in offsets]
        maps = []
    else:
        if offsets:
            raise InputError(f"{name}: key '{offsets[0]}_offset_deg' in an errormap result (the map level "
                             f"absorbs the offset)")
        offset_values, maps = None, _load_maps(data, name, chain, outside, JointMap, ErrorMap)
    dropped = [(d.get("parameter", "?"), d.get("reason", "")) for d in data.get("dropped", []) if isinstance(d, dict)]
    compliant = [j for j in chain.joint_names if f"{j}_compliance_deg_per_Nm" in data]
    compliance = [float(json_numbers(data, name, f"{j}_compliance_deg_per_Nm")) for j in compliant]
    held_tool = [p for p, _ in dropped if p in ("tool_x_mm", "tool_y_mm", "tool_z_mm")]  # a planar robot's
    try:
        model = SerialPositionModel(chain, kind, geometric, params, offsets, maps, dropped, offset_values,
                                    compliant, compliance, held_tool)
    except ValueError as e:
        raise InputError(f"{name}: {e}") from None
    P = json_numbers(data, name, "stations_mm", (None, 3)) if "stations_mm" in data else None
    d0 = json_numbers(data, name, "dead_paths_mm", (len(P),)) if P is not None else None
    if P is not None and "station_labels" in data:
        labels = json_numbers(data, name, "station_labels", (len(P),))
        if np.any(labels < 0) or np.any(labels != np.round(labels)) or len(set(labels)) != len(labels):
            raise InputError(f"{name}: key 'station_labels': distinct whole numbers >= 0 expected")
    frame = None
    if isinstance(data.get("tracker_frame"), dict):
        tf = data["tracker_frame"]
        frame = np.concatenate([json_numbers(tf, name, "translation_mm", (3,), label="tracker_frame.translation_mm"),
                                json_numbers(tf, name, "rotation_deg", (3,), label="tracker_frame.rotation_deg")])
    C, cov_names = _load_covariance(data, name, model)
    return SerialResult(model, P, d0, frame, data, str(resolve_robot(robot["file"],
                                                                     os.path.dirname(os.path.abspath(name)))),
                        C, cov_names)


def _load_covariance(data, name, model):
    """(C (N, N), names) of a result's ``covariance`` (:func:`covariance_entry`), checked: names distinct strings
    covering the model's parameters, N (N + 1) / 2 finite numbers, a diagonal >= 0; (None, None) when absent or
    omitted."""
    entry = data.get("covariance")
    if entry is None:
        return None, None
    if not isinstance(entry, dict):
        raise InputError(f"{name}: key 'covariance' must be an object (names, lower)")
    names = entry.get("names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise InputError(f"{name}: key 'covariance.names' must be a list of distinct parameter names")
    if "lower" not in entry:
        if entry.get("omitted"):
            return None, None
        raise InputError(f"{name}: missing key 'covariance.lower'")
    n = len(names)
    lower = json_numbers(entry, name, "lower", (n * (n + 1) // 2,), label="covariance.lower")
    C = np.zeros((n, n))
    C[np.tril_indices(n)] = lower
    C = C + np.tril(C, -1).T
    if np.any(np.diag(C) < 0):
        raise InputError(f"{name}: key 'covariance.lower': a negative variance (the diagonal must be >= 0)")
    missing = [p for p in model.names if p not in names]
    if missing:
        raise InputError(f"{name}: key 'covariance.names': no row for the model's parameter {missing[0]}")
    return C, tuple(names)


def _load_maps(data, name, chain, outside, JointMap, ErrorMap):
    maps = data.get("error_map")
    if not isinstance(maps, dict) or not maps:
        raise InputError(f"{name}: missing key 'error_map' (model errormap)")
    out = []
    for joint, m in maps.items():
        label = f"error_map.{joint}."
        if joint not in chain.joint_names:
            raise InputError(f"{name}: key 'error_map.{joint}': no such joint on the chain "
                             f"({', '.join(chain.joint_names)})")
        if not isinstance(m, dict):
            raise InputError(f"{name}: key 'error_map.{joint}' must be an object")
        grid = json_numbers(m, name, "grid_deg", (None,), label=label + "grid_deg")
        if not grid.size or np.any(np.diff(grid) <= 0):
            raise InputError(f"{name}: key '{label}grid_deg': the map nodes must be strictly ascending")
        fwd = json_numbers(m, name, "forward_deg", (len(grid),), label=label + "forward_deg")
        bidirectional = "reverse_deg" in m
        rev = json_numbers(m, name, "reverse_deg", (len(grid),), label=label + "reverse_deg") if bidirectional else fwd
        try:
            out.append(JointMap(ErrorMap(grid, fwd, rev, axis=joint, outside=outside), bidirectional))
        except ValueError as e:
            raise InputError(f"{name}: {e}") from None
    return out
