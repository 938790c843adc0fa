"""Measurement plan files of a SCARA campaign (paper 000 §4.1, Eq. (11)-(12)): reader and writer.

CSV ``theta1_deg,theta2_deg,measure`` (angles in degrees; ``#`` comment lines, one header row), or a
YAML :class:`~olti_drake.model.plan.BidirectionalGrid` mapping (``.yaml``/``.yml``). The plan itself
(:class:`~olti_drake.model.plan.Plan`, the paper's bidirectional grid) is :mod:`olti_drake.model.plan`.
"""

from pathlib import Path

import numpy as np

from olti_drake.io.csvio import check_finite, check_values, read_table, read_yaml
from olti_drake.io.outputs import writing
from olti_drake.model.plan import BidirectionalGrid, Plan

COLUMNS = ("theta1_deg", "theta2_deg", "measure")
#: Columns of a campaign (readings), never of a plan: a file with one is refused as a plan, naming it.
CAMPAIGN_COLUMNS = ("displacement_mm",)


def _fmt(x: float) -> str:
    """Shortest of '%.15g' (prints -140 as '-140') and repr that round-trips exactly."""
    s = "%.15g" % x
    return s if float(s) == x else repr(float(x))


def save_plan(plan: Plan, path) -> None:
    """Write ``plan`` as CSV (angles in degrees, 000 §4.1 Eq. (11)-(12)).

    One ``#`` comment line, header ``theta1_deg,theta2_deg,measure``, values
    that round-trip exactly, measure as 0/1.
    """
    with writing(path, newline="") as f:
        f.write("# olti_drake measurement plan (paper 000 sec. 4.1): commanded joint angles in "
                "degrees, in execution order, row 1 = start; measure 1 = interferometer "
                "reading, 0 = pass-through move; approach directions follow formats.md\n")
        f.write(",".join(COLUMNS) + "\n")
        for t1, t2, m in zip(plan.theta1_deg, plan.theta2_deg, plan.measure):
            f.write(f"{_fmt(t1)},{_fmt(t2)},{int(m)}\n")


def _load_yaml(path: Path) -> Plan:
    from pydrake.common.yaml import yaml_load_typed

    read_yaml(path, "plan")  # refuses duplicate keys and non-UTF-8 bytes, naming the line
    try:
        grid = yaml_load_typed(schema=BidirectionalGrid, filename=str(path))
        return grid.plan()
    except Exception as exc:  # pydrake raises RuntimeError/KeyError/...: one line naming the file
        msg = " ".join(str(exc).split())
        raise ValueError(f"{path}: not a valid BidirectionalGrid plan: {msg}") from None


def load_plan(path) -> Plan:
    """Read a plan file: CSV (angles in degrees) or YAML :class:`~olti_drake.model.plan.BidirectionalGrid`.

    CSV: ``#`` comment lines, one header row, columns in any order,
    ``theta1_deg`` and ``theta2_deg`` required, ``measure`` (0/1) optional
    (default 1), extra columns ignored. Errors are one-line ``ValueError``s
    naming the file, the 1-based line and the column. (000 §4.1, Eq. (11)-(12).)
    """
    path = Path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        return _load_yaml(path)
    t = read_table(path, COLUMNS[:2], optional=COLUMNS[2:] + CAMPAIGN_COLUMNS)
    campaign = [c for c in CAMPAIGN_COLUMNS if c in t]
    if campaign:  # a campaign's readings at the commands: its angles read as a plan would repeat every reflector
        raise ValueError(f"{path}: a campaign (it has the readings' column '{campaign[0]}'), not a plan: a plan "
                         f"is the commanded angles only (theta1_deg,theta2_deg[,measure], e.g. "
                         f"data/plan_paper000.csv, or a BidirectionalGrid YAML such as data/plan_paper000.yaml)")
    check_finite(t, path, [c for c in COLUMNS if c in t])
    if "measure" in t:
        check_values(t, path, "measure", (0.0, 1.0))
    measure = t["measure"] == 1.0 if "measure" in t else np.ones(len(t["_line"]), dtype=bool)
    try:
        return Plan(t["theta1_deg"], t["theta2_deg"], measure)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
