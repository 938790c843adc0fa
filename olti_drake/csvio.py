"""CSV tables in the shared format (shared/spec/formats.md).

Comma separated, one header row, ``#`` starts a comment line, UTF-8; required
columns in any order, extra columns ignored. Every error is one line
``FILE:LINE: column 'NAME': ...`` with the 1-based line number an editor shows.
"""

from __future__ import annotations

import csv
import os
from typing import Dict, Iterable, Sequence

import numpy as np


class InputError(ValueError):
    """Bad input file or parameter; the message is one line, ready for the user."""


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
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            text = f.read()
    except OSError as e:
        raise InputError(f"{name}: cannot read ({e.strerror})") from None
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
    """Raise naming file, line and column of the first non-finite value (in ``rows`` if given)."""
    sel = np.arange(len(table["_line"])) if rows is None else np.flatnonzero(rows)
    for c in columns:
        bad = sel[~np.isfinite(table[c][sel])]
        if bad.size:
            raise InputError(f"{os.fspath(path)}:{table['_line'][bad[0]]}: column '{c}': "
                             f"{table[c][bad[0]]:g} is not finite")


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
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as e:
        raise InputError(f"{name}: cannot read ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{name}:{e.lineno}: not valid JSON ({e.msg})") from None
    if not isinstance(data, dict):
        raise InputError(f"{name}: not a JSON object")
    allowed = (fmt,) if isinstance(fmt, str) else tuple(fmt or ())
    if allowed and data.get("format") not in allowed:
        want = " or ".join(repr(f) for f in allowed)
        raise InputError(f"{name}: 'format' must be {want}{' for ' + what if what else ''}, "
                         f"got {data.get('format')!r}")
    return data


def write_table(path, columns: Dict[str, Sequence], formats: Dict[str, str],
                comments: Sequence[str] = ()) -> None:
    """Write a CSV with ``# comment`` lines, a header and one row per entry.

    ``formats`` maps column -> %-format; deterministic output (same data, same
    bytes) is what makes campaigns reproducible byte for byte.
    """
    names = list(columns)
    n = len(columns[names[0]])
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        for c in comments:
            f.write(f"# {c}\n")
        f.write(",".join(names) + "\n")
        for r in range(n):
            f.write(",".join(_fmt(formats.get(c, "%.12g"), columns[c][r]) for c in names) + "\n")


def _fmt(fmt: str, v) -> str:
    s = fmt % v
    return "0" if s in ("-0", "-0.0") else s
