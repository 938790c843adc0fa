"""The campaign log of ``olti run``: every reading on disk as it arrives, and where to resume.

A run directory holds three files (docs/runner.md):

- ``campaign.csv``: the SCARA campaign of shared/spec/formats.md (mm, deg),
  one row per reading, appended, flushed and ``fsync``-ed as it arrives,
  with the extra columns ``plan_row``, ``step`` (index in the whole command
  sequence: reflector run × plan rows + plan row), ``session`` (0 for the
  first run, n for the n-th ``--resume``), the counter's raw ``status``,
  ``reads`` and ``rezeros`` (the beam-loss policy's attempts), ``time_utc``
  and ``elapsed_s`` (wall clock; seconds since the session started).
- ``events.jsonl``: one JSON object per line: sessions, counter zeroings (the
  run's reference pose, which a resume returns to), re-reads, re-zeroings,
  re-approaches, alarms, interruptions.
- ``run.json``: what the campaign is (scenario, fingerprint of its command
  sequence, the planned readings) and its sessions; replaced atomically.

Appending whole lines, each flushed before the next reading is taken, is
what makes ``kill -9`` safe: at most the last line is cut short, and a
resume drops that fragment (the reading is taken again).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import RUN as FORMAT

COLUMNS = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "displacement_mm", "theta4_deg", "valid",
           "plan_row", "step", "session", "status", "reads", "rezeros", "time_utc", "elapsed_s")
#: The files of a run directory: all measured data, never replaced (olti_drake.io.outputs).
RUN_FILES = ("campaign.csv", "events.jsonl", "run.json", "truth.json")
_FORMATS = ("%d", "%.12g", "%.12g", "%d", "%d", "%.9f", "%.9f", "%d", "%d", "%d", "%d", "%s", "%d", "%d", "%s",
            "%.3f")


#: The run-log columns after a campaign's own (both kinds): where and when each reading was taken.
_LOG_COLUMNS = ("plan_row", "step", "session", "status", "reads", "rezeros", "time_utc", "elapsed_s")
_LOG_FORMATS = ("%d", "%d", "%d", "%s", "%d", "%d", "%s", "%.3f")


def serial_columns(n_joints: int) -> tuple:
    """The columns of a six-axis run log: the N-joint distance campaign (station, theta<i>_deg, dir<i>,
    displacement_mm, valid: formats.md, serial robots) and the run-log columns."""
    return (("station",) + tuple(f"theta{i + 1}_deg" for i in range(n_joints)) +
            tuple(f"dir{i + 1}" for i in range(n_joints)) + ("displacement_mm", "valid") + _LOG_COLUMNS)


#: The 3D machine tool's campaign columns (formats.md "Machine tool in 3D", as ``olti simulate`` writes them).
MACHINE3D_COLUMNS = ("station", "target", "x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "tool", "displacement_mm", "valid")


#: A tracker campaign's measured values after the joints (formats.md "Point campaign (laser tracker)", tracker
#: frame, mm) and the environment the tracker used with each reading (°C, hPa, %RH: docs/tracker.md).
TRACKER_COLUMNS = ("x_mm", "y_mm", "z_mm", "valid", "temperature_c", "pressure_hpa", "humidity_pct")
_FLOAT_COLUMNS = ("displacement_mm",) + TRACKER_COLUMNS[:3] + TRACKER_COLUMNS[4:]


def tracker_columns(n_joints: int) -> tuple:
    """The columns of a tracker run log: theta<i>_deg, dir<i>, :data:`TRACKER_COLUMNS` and the run-log columns."""
    return (tuple(f"theta{i + 1}_deg" for i in range(n_joints)) + tuple(f"dir{i + 1}" for i in range(n_joints))
            + TRACKER_COLUMNS + _LOG_COLUMNS)


def machine3d_columns() -> tuple:
    """The columns of a 3D machine run log: the 3D machine campaign's (station = pan/tilt head, target,
    x/y/z_cmd_mm, tool, displacement_mm, valid) and the run-log columns (``plan_row`` = the target)."""
    return MACHINE3D_COLUMNS + _LOG_COLUMNS


#: A five-axis distance campaign's columns after the commands and directions (formats.md "Five-axis machine tools").
MACHINE5_COLUMNS = ("tool", "station", "station_frame", "displacement_mm", "valid")


def machine5_columns(axes) -> tuple:
    """The columns of a five-axis run log: the machine's command columns (``x_cmd_mm`` ..., ``a_cmd_deg`` ...),
    ``dir_<axis>`` per axis, :data:`MACHINE5_COLUMNS` and the run-log columns (``plan_row`` = the plan's row)."""
    from olti_drake.io.five_axis_io import command_columns

    return command_columns(axes) + tuple(f"dir_{a.lower()}" for a in axes) + MACHINE5_COLUMNS + _LOG_COLUMNS


def _formats_of(columns) -> tuple:
    """The value formats of a log's columns (the SCARA's as they always were)."""
    if tuple(columns) == COLUMNS:
        return _FORMATS
    head = tuple("%.12g" if c.startswith("theta") or c.endswith(("_cmd_mm", "_cmd_deg")) else "%.9f" if c in
                 _FLOAT_COLUMNS else "%s" if c == "station_frame" else "%d" for c in columns[:-len(_LOG_COLUMNS)])
    return head + _LOG_FORMATS


def utc_now() -> str:
    """The wall clock as ISO 8601 UTC with milliseconds (``2026-11-24T14:05:09.123Z``)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def _append(f, text: str, fsync: bool) -> None:
    f.write(text)
    f.flush()
    if fsync:
        os.fsync(f.fileno())


class CampaignLog:
    """An open run directory: append readings and events; knows which steps are on disk.

    Create with :meth:`create` (a new campaign) or :meth:`reopen` (``--resume``).
    ``recorded``: the steps whose reading is in ``campaign.csv``.
    """

    def __init__(self, out_dir: str, manifest: dict, recorded: set, fsync: bool = True):
        self.out_dir = out_dir
        self.manifest = manifest
        self.formats = _formats_of(manifest.get("columns", COLUMNS))
        self.recorded = set(recorded)
        self.fsync = fsync
        self.session = len(manifest["sessions"])
        self._t0 = time.monotonic()
        self._csv = open(self.path("campaign.csv"), "a", encoding="utf-8", newline="")
        self._events = open(self.path("events.jsonl"), "a", encoding="utf-8")

    def path(self, name: str) -> str:
        return os.path.join(self.out_dir, name)

    # ------------------------------------------------------------------ opening

    @classmethod
    def create(cls, out_dir: str, manifest: dict, comments=(), fsync: bool = True, columns=None) -> "CampaignLog":
        """Start a new campaign in ``out_dir``; refuses a directory that already holds one.

        ``columns``: the log's columns (default the SCARA's, ``COLUMNS``; a six-axis run's are
        :func:`serial_columns`, then kept in ``run.json`` for the resume)."""
        from olti_drake.io.outputs import make_dir, writing

        csv_path = cls.check_new(out_dir)
        make_dir(out_dir)
        # Measurements: created only where no file is (outputs.writing never replaces one).
        with writing(csv_path, measurement=True, fsync=fsync, newline="") as f:
            f.write("".join(f"# {c}\n" for c in comments) + ",".join(columns or COLUMNS) + "\n")
        with writing(os.path.join(out_dir, "events.jsonl"), measurement=True, fsync=fsync):
            pass
        manifest = dict(manifest, format=FORMAT, sessions=[], complete=False)
        if columns is not None and tuple(columns) != COLUMNS:
            manifest["columns"] = list(columns)
        _write_json(os.path.join(out_dir, "run.json"), manifest)
        return cls(out_dir, manifest, set(), fsync)

    @staticmethod
    def check_new(out_dir: str) -> str:
        """The campaign path of a new run in ``out_dir``; a one-line error if a campaign or a run log is
        there, or the directory cannot be made (:func:`olti_drake.io.outputs.preflight`)."""
        from olti_drake.io.outputs import preflight

        csv_path = os.path.join(out_dir, "campaign.csv")
        if os.path.exists(csv_path):
            raise InputError(f"{csv_path} exists: continue that campaign with --resume, or choose another --out")
        preflight((), measurements=[os.path.join(out_dir, n) for n in RUN_FILES], dirs=[out_dir], create_dirs=True)
        return csv_path

    @classmethod
    def reopen(cls, out_dir: str, fsync: bool = True) -> "CampaignLog":
        """Reopen an interrupted campaign: repair a cut last line, read the recorded steps."""
        run_path = os.path.join(out_dir, "run.json")
        if not os.path.exists(run_path):
            raise InputError(f"{run_path}: no campaign to resume there (start one without --resume)")
        try:
            with open(run_path, encoding="utf-8") as f:
                manifest = json.load(f)
        except (OSError, ValueError) as e:
            raise InputError(f"{run_path}: unreadable ({' '.join(str(e).split())})") from None
        if manifest.get("format") != FORMAT:
            raise InputError(f"{run_path}: format {manifest.get('format')!r}, expected {FORMAT!r}")
        csv_path = os.path.join(out_dir, "campaign.csv")
        cut = _drop_partial_line(csv_path)
        _drop_partial_line(os.path.join(out_dir, "events.jsonl"))
        log = cls(out_dir, manifest, _recorded_steps(csv_path), fsync)
        if cut:
            log.event("dropped_partial_line", file="campaign.csv", text=cut)
        return log

    # ------------------------------------------------------------------ writing

    def begin_session(self, start_step: int, **info) -> None:
        """Note a session in run.json and events.jsonl (``start_step``: first step it runs)."""
        entry = {"session": self.session, "started_utc": utc_now(), "start_step": int(start_step), **info}
        self.manifest["sessions"].append(entry)
        _write_json(self.path("run.json"), self.manifest)
        self.event("session", **entry)

    def end_session(self, outcome: str, complete: bool = False, **info) -> None:
        entry = self.manifest["sessions"][-1]
        entry.update(ended_utc=utc_now(), outcome=outcome, readings_on_disk=len(self.recorded), **info)
        self.manifest["complete"] = bool(complete)
        _write_json(self.path("run.json"), self.manifest)
        self.event("end", outcome=outcome, **info)

    def append(self, step: int, record: tuple, status) -> None:
        """Write one reading (a ``CampaignRecorder`` row and its ReadStatus) and flush it to disk."""
        values = (*record, step, self.session, status.raw or "-", status.reads, status.rezeros, utc_now(),
                  time.monotonic() - self._t0)
        line = ",".join(_fmt(f, v) for f, v in zip(self.formats, values)) + "\n"
        _append(self._csv, line, self.fsync)
        self.recorded.add(int(step))

    def event(self, kind: str, **fields) -> None:
        """Append one event (JSON line) and flush it."""
        obj = {"time_utc": utc_now(), "session": self.session, "kind": kind}
        obj.update({k: _plain(v) for k, v in fields.items()})
        _append(self._events, json.dumps(obj) + "\n", self.fsync)

    def close(self) -> None:
        self._csv.close()
        self._events.close()

    # ------------------------------------------------------------------ reading

    def zero_pose(self, reflector: int) -> Optional[tuple]:
        """The command (N, deg/mm) and directions (N) where reflector's run was first zeroed, if logged
        (and, for a tracer head, the head's aim (2, deg) then)."""
        with open(self.path("events.jsonl"), encoding="utf-8") as f:
            for line in f:
                e = json.loads(line)
                if e.get("kind") == "zero" and e.get("reflector") == reflector and not e.get("again"):
                    pose = (np.array(e["command"], dtype=float), np.array(e["directions"], dtype=float))
                    return pose + ((np.array(e["aim"], dtype=float),) if "aim" in e else ())
        return None


def _fmt(fmt: str, v) -> str:
    if fmt == "%s":
        return str(v).replace(",", " ")
    if fmt != "%d" and isinstance(v, float) and not np.isfinite(v):
        return "nan"
    return fmt % v


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def _write_json(path: str, obj: dict) -> None:
    """Replace the run's own ``path`` atomically (a temporary file, fsync, rename: outputs.writing)."""
    from olti_drake.io.outputs import writing

    with writing(path, fsync=True) as f:
        json.dump(obj, f, indent=1)
        f.write("\n")


def _drop_partial_line(path: str) -> str:
    """Truncate a last line that was cut short (no newline); returns the dropped text."""
    try:
        with open(path, "rb+") as f:
            data = f.read()
            if not data or data.endswith(b"\n"):
                return ""
            keep = data.rfind(b"\n") + 1
            f.truncate(keep)
            return data[keep:].decode("utf-8", "replace")
    except FileNotFoundError:
        return ""


def _recorded_steps(csv_path: str) -> set:
    """The ``step`` of every reading in a run's campaign.csv; one-line errors for a damaged file."""
    from olti_drake.io.csvio import read_table

    if not os.path.exists(csv_path):
        raise InputError(f"{csv_path}: missing; the campaign cannot be resumed")
    with open(csv_path, encoding="utf-8") as f:
        data_rows = sum(1 for line in f if line.strip() and not line.startswith("#")) - 1
    if data_rows <= 0:
        return set()
    t = read_table(csv_path, ("step",), integer=("step",))
    steps = t["step"].astype(int)
    dup = steps[np.flatnonzero(np.diff(np.sort(steps)) == 0)]
    if dup.size:
        line = t["_line"][np.flatnonzero(steps == dup[0])[1]]
        raise InputError(f"{csv_path}:{line}: step {dup[0]} is recorded twice")
    return set(steps.tolist())
