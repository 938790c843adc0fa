"""CSV tables of the tool's files (campaigns, plans, maps; their columns are listed where each is read).

Comma separated, one header row, ``#`` starts a comment line, UTF-8; required
columns in any order, extra columns ignored. Every error is one line
``FILE:LINE: column 'NAME': ...`` with the 1-based line number an editor shows.

The SCARA campaign (:func:`load_campaign` below): Reading SCARA campaign files for identification: one reading d_j(k) of Eq. (10) of 000 per row, columns :data:`REQUIRED`.

Units: mm and degrees. Rows with ``valid`` = 0 are kept in the file and
skipped here; every error names the file, the line and the column.

Tables are written by :func:`write_table` (deterministic, atomic); the machine-tool campaign of 001
(2D and 3D) by :func:`write_machine_campaign`.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from typing import Dict, Iterable, Sequence

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.scara import JointCommands
from olti_drake.units import unit_bound


def read_text(path, what: str = "") -> str:
    """The text of a UTF-8 file (a leading BOM dropped); one-line errors name the file, and for bytes that
    are not UTF-8 the 1-based line of the first one (``what`` names the file's role if it is missing)."""
    name = os.fspath(path)
    if not name:
        raise InputError(f"the {what or 'input file'} path is empty")
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except FileNotFoundError:
        raise InputError(f"{name}: {what + ' ' if what else ''}file not found") from None
    except OSError as e:
        raise InputError(f"{name}: cannot read ({e.strerror})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise InputError(f"{name}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x}); "
                         f"save the file as UTF-8") from None


def read_yaml(path, what: str = ""):
    """Plain data of a YAML file (tags such as ``!Simulated`` read as their plain mapping), refusing what
    a YAML parser silently accepts: a key given twice in one mapping (the last would win), and bytes that
    are not UTF-8. Every YAML reader calls this first; errors are one line naming the file and line."""
    import yaml

    name = os.fspath(path)
    text = read_text(path, what)

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                if key != "<<" and isinstance(key, (str, int, float, bool)) and key in seen:
                    raise InputError(f"{name}:{line}: duplicate key {key!r} (first on line {seen[key]}); "
                                     f"a key may appear once per mapping")
                seen.setdefault(key, line)
            return super().construct_mapping(node, deep=deep)

    def tagged(loader, suffix, node):  # a typed scenario node (!Emulated {...}): check it as plain data
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node, deep=True)
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    Loader.add_multi_constructor("!", tagged)
    try:
        return yaml.load(text, Loader=Loader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f":{mark.line + 1}" if mark is not None else ""
        raise InputError(f"{name}{at}: not valid YAML ({getattr(e, 'problem', None) or e})") from None


def read_table(path, required: Sequence[str], optional: Iterable[str] = (),
               integer: Iterable[str] = ()) -> Dict[str, np.ndarray]:
    """Read numeric columns of a CSV file.

    Args:
        path: CSV file.
        required: columns that must be present.
        optional: columns read when present (absent ones are not in the result).
        integer: columns whose values must be whole numbers.

    Returns:
        dict column -> float array, plus ``"_line"``: the 1-based file line of
        every data row (for row-numbered errors later).
    """
    name = os.fspath(path)
    text = read_text(path)
    rows = [(i + 1, line) for i, line in enumerate(text.splitlines())
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{name}: empty file (no header row)")
    header_line, header = rows[0]
    cols = [c.strip() for c in next(csv.reader([header]))]
    dup = [c for c in cols if cols.count(c) > 1]
    if dup:
        raise InputError(f"{name}:{header_line}: duplicate column '{dup[0]}'")
    missing = [c for c in required if c not in cols]
    if missing:
        raise InputError(f"{name}:{header_line}: missing required column '{missing[0]}' "
                         f"(header has {', '.join(cols)})")
    if len(rows) == 1:
        raise InputError(f"{name}: empty file (no data rows)")
    index = {c: cols.index(c) for c in list(required) + list(optional) if c in cols}
    integer = set(integer)
    out = {c: np.empty(len(rows) - 1) for c in index}
    lines = np.empty(len(rows) - 1, dtype=int)
    first_seen, same_as = {}, np.empty(len(rows) - 1, dtype=int)
    for r, (lineno, line) in enumerate(rows[1:]):
        fields = [f.strip() for f in next(csv.reader([line]))]
        if len(fields) != len(cols):
            raise InputError(f"{name}:{lineno}: expected {len(cols)} fields as in the header, got {len(fields)}")
        lines[r] = lineno
        same_as[r] = first_seen.setdefault(tuple(fields), lineno)
        for c, j in index.items():
            raw = fields[j]
            try:
                v = float(raw)
            except ValueError:
                raise InputError(f"{name}:{lineno}: column '{c}': "
                                 f"{'missing value' if not raw else repr(raw) + ' is not a number'}") from None
            if c in integer and np.isfinite(v) and v != round(v):
                raise InputError(f"{name}:{lineno}: column '{c}': {raw!r} is not a whole number")
            out[c][r] = v
    out["_line"] = lines
    out["_same_as"] = same_as  # the first line identical in every column (its own line if none)
    return out


def check_no_duplicate_rows(table: Dict[str, np.ndarray], path) -> None:
    """Refuse a row identical in every column to an earlier one (e.g. a campaign glued twice), naming both
    lines: the same reading twice would count twice and shrink every uncertainty by sqrt(2)."""
    if "_same_as" not in table:
        return
    dup = np.flatnonzero(np.asarray(table["_same_as"]) != table["_line"])
    if dup.size:
        k = dup[0]
        raise InputError(f"{os.fspath(path)}:{table['_line'][k]}: row identical in every column to line "
                         f"{int(table['_same_as'][k])} ({dup.size} such row(s); a file appended twice?) -- "
                         f"a reading counted twice would shrink the uncertainties; remove the copies")


def data_digest(*columns) -> dict:
    """{"readings": N, "sha256": hex} of the data rows used (float64 columns, little-endian, in order): the
    identity of a campaign whatever its comments, column order or number formatting."""
    import hashlib

    a = np.column_stack([np.asarray(c, dtype="<f8") for c in columns])
    return {"readings": int(len(a)), "sha256": hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()}


def check_finite(table: Dict[str, np.ndarray], path, columns: Iterable[str], rows=None) -> None:
    """Raise naming file, line and column of the first value (in ``rows`` if given) that is not finite or
    lies beyond the physical bound of its column's unit (:data:`olti_drake.units.UNIT_BOUNDS`: +-720 deg,
    +-1e5 mm)."""
    sel = np.arange(len(table["_line"])) if rows is None else np.flatnonzero(rows)
    for c in columns:
        v = table[c][sel]
        bad = sel[~np.isfinite(v)]
        if bad.size:
            raise InputError(f"{os.fspath(path)}:{table['_line'][bad[0]]}: column '{c}': "
                             f"{table[c][bad[0]]:g} is not finite")
        bound = unit_bound(c)
        bad = sel[np.abs(v) > bound]
        if bad.size:
            unit = "deg" if c.endswith("_deg") else "mm"
            raise InputError(f"{os.fspath(path)}:{table['_line'][bad[0]]}: column '{c}': {table[c][bad[0]]:g} "
                             f"is beyond +-{bound:g} {unit}, outside any physical range (a unit or typing slip?)")


def check_spread(values, groups, lines, source, column: str, max_span: float, group: str, why: str) -> None:
    """Refuse a reading that cannot belong with the others of its group (e.g. one reflector's readings).

    The readings of one fixed point lie in an interval of width at most ``max_span`` (mm: the size of
    the region the moving point covers, ``why`` says it), so, while most of them are right, the median
    lies in that interval and every right reading is within ``max_span`` of it. The one farthest beyond
    is named by file line and column, before a solver turns it into "not identifiable". ``why`` completes
    "the ... they can span (WHY)".
    """
    values, groups, lines = (np.asarray(a) for a in (values, groups, lines))
    for g in np.unique(groups):
        sel = np.flatnonzero(groups == g)
        dev = np.abs(values[sel] - np.median(values[sel]))
        k = sel[np.argmax(dev)]
        if dev.max() > max_span:
            unit = column.rsplit("_", 1)[-1]
            raise InputError(f"{os.fspath(source)}:{lines[k]}: column '{column}': {values[k]:g} {unit} is "
                             f"{dev.max():.6g} {unit} from the median of {group} {g:g}'s readings, more than the "
                             f"{max_span:.6g} {unit} they can span ({why})")


def check_values(table: Dict[str, np.ndarray], path, column: str, allowed) -> None:
    """Raise naming file, line and column of the first value not in ``allowed``."""
    bad = np.flatnonzero(~np.isin(table[column], allowed))
    if bad.size:
        raise InputError(f"{os.fspath(path)}:{table['_line'][bad[0]]}: column '{column}': "
                         f"{table[column][bad[0]]:g} is not one of {', '.join(f'{a:g}' for a in allowed)}")


def check_indices(table: Dict[str, np.ndarray], path, column: str) -> np.ndarray:
    """The column as int indices: whole numbers >= 0, every index 0..max used; errors name file, line, column."""
    v = table[column]
    bad = np.flatnonzero((v < 0) | (v != np.round(v)))
    if bad.size:
        raise InputError(f"{os.fspath(path)}:{table['_line'][bad[0]]}: column '{column}': {v[bad[0]]:g} is not "
                         f"an index >= 0")
    idx = v.astype(int)
    missing = sorted(set(range(idx.max() + 1)) - set(idx))
    if missing:
        raise InputError(f"{os.fspath(path)}: {column} index {missing[0]} has no valid reading "
                         f"(indices must run 0..{idx.max()})")
    return idx


def read_json(path, fmt, what: str = "") -> dict:
    """A JSON object whose ``format`` must be ``fmt`` (a string, a tuple of allowed ones, or None for
    any); ``what`` names the file's role in the message. One-line errors name the file (and line)."""
    import json

    name = os.fspath(path)
    text = read_text(path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        hint = f"; expected {what}, is it another kind of file?" if what and (e.lineno, e.colno) == (1, 1) else ""
        raise InputError(f"{name}:{e.lineno}: not valid JSON ({e.msg}){hint}") from None
    if not isinstance(data, dict):
        raise InputError(f"{name}: not a JSON object")
    allowed = (fmt,) if isinstance(fmt, str) else tuple(fmt or ())
    if allowed and data.get("format") not in allowed:
        want = " or ".join(repr(f) for f in allowed)
        raise InputError(f"{name}: 'format' must be {want}{' for ' + what if what else ''}, "
                         f"got {data.get('format')!r}")
    return data


def json_numbers(obj: dict, name, key: str, shape=(), positive: bool = False, label: str = "") -> np.ndarray:
    """The numbers under ``obj[key]`` of a JSON file as a float array, checked: present, numeric, of
    ``shape`` (a tuple, None for any length: ``(None, 2)`` is N x 2), every value finite, within the
    bound of the key's unit suffix (:data:`olti_drake.units.UNIT_BOUNDS`) and, if ``positive``, > 0.
    One-line errors name the file and the key (``label``: its dotted path, default ``key``)."""
    label = label or key
    where = f"{os.fspath(name)}: key '{label}'"
    if key not in obj:
        raise InputError(f"{os.fspath(name)}: missing key '{label}'")
    raw = obj[key]
    try:
        v = np.asarray(raw, dtype=float)
        if any(isinstance(x, (str, bool)) for x in np.ravel(np.asarray(raw, object))):  # float() takes "3", True
            raise TypeError
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected {_shape_text(shape)}, got {_short(raw)}") from None
    if v.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, v.shape)):
        raise InputError(f"{where}: expected {_shape_text(shape)}, got {_shape_text(v.shape)}")
    bad = np.flatnonzero(~np.isfinite(v.ravel()) | (np.abs(v.ravel()) > unit_bound(key))
                         | ((v.ravel() <= 0) if positive else False))
    if bad.size:
        at = f"[{', '.join(str(i) for i in np.unravel_index(bad[0], v.shape))}]" if v.ndim else ""
        bound = unit_bound(key)
        need = ", ".join(["finite"] + ["> 0"] * positive
                         + [f"within +-{bound:g} {key.rsplit('_', 1)[-1]}"] * bool(np.isfinite(bound)))
        raise InputError(f"{where}{at}: {float(v.ravel()[bad[0]]):g} is not a plausible value (must be {need})")
    return v


def _shape_text(shape) -> str:
    if not len(shape):
        return "a number"
    return ("a list of " if len(shape) == 1 else "an array of ") + " x ".join("N" if n is None else str(n)
                                                                            for n in shape) + " numbers"


def _short(raw) -> str:
    text = repr(raw)
    return text if len(text) <= 40 else text[:37] + "..."


def write_table(path, columns: Dict[str, Sequence], formats: Dict[str, str],
                comments: Sequence[str] = (), measurement: bool = False) -> None:
    """Write a CSV with ``# comment`` lines, a header and one row per entry.

    ``formats`` maps column -> %-format; deterministic output (same data, same
    bytes) is what makes campaigns reproducible byte for byte. Written
    atomically by :func:`olti_drake.io.outputs.writing` (``measurement``: never
    replacing an existing file).
    """
    from olti_drake.io.outputs import writing

    names = list(columns)
    n = len(columns[names[0]])
    with writing(path, measurement=measurement, newline="\n") as f:
        for c in comments:
            f.write(f"# {c}\n")
        f.write(",".join(names) + "\n")
        for r in range(n):
            f.write(",".join(_fmt(formats.get(c, "%.12g"), columns[c][r]) for c in names) + "\n")


def _fmt(fmt: str, v) -> str:
    s = fmt % v
    return "0" if s in ("-0", "-0.0") else s


def write_machine_campaign(columns: dict, path) -> None:
    """The machine-tool campaign CSV of formats.md (2D, or 3D when the columns have ``z_cmd_mm``): mm."""
    fmt = {"station": "%d", "target": "%d", "x_cmd_mm": "%.6f", "y_cmd_mm": "%.6f", "z_cmd_mm": "%.6f",
           "tool": "%d", "displacement_mm": "%.9f", "valid": "%d"}
    write_table(path, {k: columns[k] for k in fmt if k in columns}, {k: v for k, v in fmt.items() if k in columns},
                comments=["olti_drake machine-tool campaign (001, formats.md): mm; valid 0 = beam lost"])


# ------------------------------------------------------------------- the SCARA campaign (formats.md)
REQUIRED = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "displacement_mm")
#: Without ``dir1, dir2`` a campaign is one-directional (formats.md, the serial robots' rule).
DIRECTIONS = ("dir1", "dir2")
OPTIONAL = ("theta4_deg", "valid")


@dataclass(frozen=True)
class CampaignData:
    """The valid readings of a campaign: reflector index j, commands, d_j(k) (mm), file lines."""

    reflector: np.ndarray
    commands: JointCommands
    displacement_mm: np.ndarray
    line: np.ndarray
    source: str = ""
    n_skipped: int = 0

    def __len__(self) -> int:
        return self.reflector.size

    @property
    def one_directional(self) -> bool:
        """The file had no direction columns: single-branch maps, no backlash identified (formats.md)."""
        return self.commands.one_directional

    @property
    def n_reflectors(self) -> int:
        return int(self.reflector.max()) + 1

    def subset(self, rows) -> "CampaignData":
        """The readings at ``rows`` (a boolean mask or indices)."""
        c = self.commands
        return CampaignData(self.reflector[rows], JointCommands(c.theta1_deg[rows], c.theta2_deg[rows],
                                                                c.dir1[rows], c.dir2[rows], c.one_directional),
                            self.displacement_mm[rows], self.line[rows], self.source, self.n_skipped)


def load_campaign(path) -> CampaignData:
    """Load a SCARA campaign CSV; skip ``valid`` = 0 rows; validate what is used.

    Checks (one-line errors): required columns, numbers, finite values in the
    valid rows, directions ±1, reflector indices whole numbers 0..N_t-1 with
    every index used. ``dir1, dir2`` are optional (both or neither): without them the campaign is
    one-directional (:attr:`CampaignData.one_directional`).
    """
    name = os.fspath(path)
    t = read_table(path, [c for c in REQUIRED if c not in DIRECTIONS], OPTIONAL + DIRECTIONS,
                   integer=("reflector", "dir1", "dir2", "valid"))
    directions = _has_directions(t, path)
    required = REQUIRED if directions else tuple(c for c in REQUIRED if c not in DIRECTIONS)
    if "valid" in t:
        check_values(t, path, "valid", (0.0, 1.0))
    keep = t["valid"] == 1 if "valid" in t else np.ones(t["_line"].size, dtype=bool)
    if not keep.any():
        raise InputError(f"{name}: no valid readings (every row has valid = 0)")
    t = {k: v[keep] for k, v in t.items()}
    check_no_duplicate_rows(t, path)
    check_finite(t, path, required)
    for c in DIRECTIONS if directions else ():
        check_values(t, path, c, (-1.0, 1.0))
    j = check_indices(t, path, "reflector")
    cmd = (JointCommands(t["theta1_deg"], t["theta2_deg"], t["dir1"], t["dir2"]) if directions
           else JointCommands.without_directions(t["theta1_deg"], t["theta2_deg"]))
    return CampaignData(j, cmd, t["displacement_mm"], t["_line"], name, int((~keep).sum()))


def _has_directions(table: Dict[str, np.ndarray], path) -> bool:
    """Does a table read with ``dir1, dir2`` optional have them? Both or neither: one alone is a slip, not a
    one-directional file, and is refused naming the other as missing."""
    present = [c for c in DIRECTIONS if c in table]
    if len(present) == 1:
        other = DIRECTIONS[1 - DIRECTIONS.index(present[0])]
        raise InputError(f"{os.fspath(path)}: missing required column '{other}' (it has '{present[0]}'; "
                         f"a one-directional file has neither)")
    return bool(present)


def campaign_digest(data) -> dict:
    """{"readings", "sha256"} of the valid readings a result was identified from (SCARA, machine or N-joint
    campaign: the last digests itself, ``SerialCampaign.digest``)."""
    if hasattr(data, "digest"):
        return data.digest()
    if hasattr(data, "commands_mm"):  # MachineCampaign; 3D: z command and tool too (2D digests unchanged)
        cmd = data.commands_mm[data.target]
        more = () if cmd.shape[1] == 2 else (cmd[:, 2], data.tool[data.target])
        return data_digest(data.station, data.target, cmd[:, 0], cmd[:, 1], *more, data.displacement_mm)
    c = data.commands
    if getattr(c, "one_directional", False):  # no direction columns: none digested
        return data_digest(data.reflector, c.theta1_deg, c.theta2_deg, data.displacement_mm)
    return data_digest(data.reflector, c.theta1_deg, c.theta2_deg, c.dir1, c.dir2, data.displacement_mm)


def check_campaign_matches(result: dict, data, result_path) -> str:
    """Refuse a campaign that is not the one the result was identified from (count and digest, naming both);
    return a note ('' when matched) -- results written before the digest existed are accepted with a note."""
    stored = result.get("campaign")
    here = campaign_digest(data)
    if not isinstance(stored, dict) or "sha256" not in stored:
        return (f"{os.fspath(result_path)} carries no campaign digest (written by an older version): not checked "
                f"that {data.source} is its campaign")
    if stored.get("sha256") != here["sha256"] or stored.get("readings") != here["readings"]:
        raise InputError(f"{data.source}: not the campaign {os.fspath(result_path)} was identified from: "
                         f"{here['readings']} valid readings, sha256 {here['sha256'][:12]}..., but the result's "
                         f"campaign has {stored.get('readings')} readings, sha256 {str(stored.get('sha256'))[:12]}...")
    return ""


def load_commands(path):
    """Load a ``commands.csv`` (θ1*, θ2* deg; dir1, dir2 ±1), formats.md -> (JointCommands, file lines).

    Without ``dir1, dir2`` the commands are one-directional (:attr:`JointCommands.one_directional`): a
    one-directional result predicts them, a bidirectional one refuses them (the predict verb)."""
    t = read_table(path, ("theta1_deg", "theta2_deg"), DIRECTIONS, integer=("dir1", "dir2"))
    directions = _has_directions(t, path)
    cols = ("theta1_deg", "theta2_deg") + (DIRECTIONS if directions else ())
    check_finite(t, path, cols)
    if not directions:
        return JointCommands.without_directions(t["theta1_deg"], t["theta2_deg"]), t["_line"]
    for c in DIRECTIONS:
        check_values(t, path, c, (-1.0, 1.0))
    return JointCommands(*(t[c] for c in cols)), t["_line"]
