"""``olti compensate R.json TARGETS.csv --out COMMANDS.csv --tables DIR [--cnc FORMAT]`` on a five-axis result:
``--tables DIR`` alone writes the error-map tables (``identified.csv``, the ``--cnc csv`` format: every identified
value by ISO name, each error-motion node with its grid angle), as ``--tables`` does on every other kind of
result; the files any format writes are named by :func:`olti_drake.io.cnc.cnc_file_names` and checked by name
before any work, so an existing one is refused in one line naming it (replaced only with ``--force``) and nothing
is written. A small errormap identification (maps every 30 deg, bidirectional) of a truth outside the family."""

import csv
import json
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io import cnc
from olti_drake.io.five_axis_io import write_five_axis_campaign
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_truth import synthetic_truth
from tests.estimation.test_five_axis_identify import SIX_TABLE_STATIONS, TRUNNION, distance_campaign, no_dropped_truth
from tests.estimation.test_five_axis_uncertainty import identified
from tests.io.test_cnc_exports import _machine, with_motions
from tests.model.test_five_axis_compensation import feasible_targets, write_targets
from olti_calls import error_line, olti_in


@pytest.fixture(scope="module")
def machine():
    return FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")


@pytest.fixture(scope="module")
def case(machine, tmp_path_factory):
    """(result path, result JSON, targets path): 40 commands from 6 table stations, errormap every 30 deg; 6
    targets with their tool directions."""
    folder = tmp_path_factory.mktemp("tables5")
    truth = no_dropped_truth(synthetic_truth(machine, seed=3))
    _, result = identified(folder, distance_campaign(machine, truth, 40, 2, SIX_TABLE_STATIONS, "workpiece"),
                           "--model", "errormap", "--grid-step-deg", "30")
    pts, dirs, _, _ = feasible_targets(machine, 6, seed=9)
    targets = write_targets(folder / "targets.csv", "x_mm,y_mm,z_mm,i,j,k,tool",
                            [list(np.round(p, 6)) + list(np.round(u, 9)) + [0] for p, u in zip(pts, dirs)])
    return result, json.loads(result.read_text()), targets


def read_rows(path):
    """{name: (value, unit, grid_deg or None)} of an identified.csv."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    assert rows[0] == ["name", "value", "unit", "grid_deg"], rows[0]
    return {r[0]: (float(r[1]), r[2], float(r[3]) if r[3] else None) for r in rows[1:]}


def test_tables_alone_write_the_error_map_tables(case, tmp_path):
    result, doc, targets = case
    out, tables = tmp_path / "cmd.csv", tmp_path / "tables"
    _, printed, _ = olti_in("compensate", result, targets, "--out", out, "--tables", tables, expect=0)
    assert out.is_file() and f"wrote {tables / 'identified.csv'}" in printed, printed
    assert sorted(os.listdir(tables)) == ["identified.csv"]
    rows = read_rows(tables / "identified.csv")
    motions = doc["error_motions"]
    assert len(motions) == 12, list(motions)  # (E_XA .. E_CC: six per rotary axis)
    n_nodes = 0
    for name, e in motions.items():
        assert "reverse" in e, name  # (a bidirectional campaign: both branches)
        for branch in ("forward", "reverse"):
            for i, (g, v) in enumerate(zip(e["grid_deg"], e[branch])):
                value, unit, grid = rows[f"{name}_{branch}_{e['unit']}[{i}]"]
                assert unit == e["unit"] and grid == pytest.approx(g, rel=0, abs=1e-9), (name, i)
                assert value == pytest.approx(v, rel=1e-12, abs=0), (name, branch, i)
                n_nodes += 1
    assert n_nodes == sum(2 * len(e["grid_deg"]) for e in motions.values()) > 100
    for name, v in doc["location_errors"].items():
        assert rows[name][0] == pytest.approx(v, rel=1e-12, abs=1e-15), name
    # ... and the same file as --cnc csv writes
    again = tmp_path / "again"
    olti_in("compensate", result, targets, "--out", tmp_path / "cmd2.csv", "--tables", again, "--cnc", "csv", expect=0)
    assert (again / "identified.csv").read_text() == (tables / "identified.csv").read_text()


#: One file each format writes (the last of several), as docs/cnc_exports.md names it.
EXISTING = {"tables": "identified.csv", "csv": "identified.csv", "heidenhain": "kinematicscomp/C_ECC.COM",
            "linuxcnc": "xyzac-trt.ini", "siemens": "swivel_data.mpf", "fanuc": "tcp_parameters.txt"}


@pytest.mark.parametrize("how", list(EXISTING))
def test_an_existing_file_of_the_export_is_refused_by_name_before_anything_is_written(case, tmp_path, how):
    result, _, targets = case
    tables, out = tmp_path / "tables", tmp_path / "cmd.csv"
    existing = tables.joinpath(*EXISTING[how].split("/"))
    existing.parent.mkdir(parents=True)
    content = b"# the operator's own file\r\n1,2,3\n"
    existing.write_bytes(content)
    extra = [] if how == "tables" else ["--cnc", how]
    code, _, err = olti_in("compensate", result, targets, "--out", out, "--tables", tables, *extra, expect=2)
    error_line(code, err, f"{existing} exists", "--force")
    assert existing.read_bytes() == content
    assert not out.exists()
    assert sorted(p.relative_to(tables).as_posix() for p in tables.rglob("*") if p.is_file()) == [EXISTING[how]]
    # --force replaces it, as any result (olti_drake.io.outputs)
    olti_in("compensate", result, targets, "--out", out, "--tables", tables, *extra, "--force", expect=0)
    assert existing.read_bytes() != content and out.is_file()


def test_a_file_where_the_tables_directory_goes_is_refused_before_anything_is_written(case, tmp_path):
    result, _, targets = case
    tables, out = tmp_path / "tables", tmp_path / "cmd.csv"
    tables.mkdir()
    (tables / "kinematicscomp").write_text("not a directory\n")
    _, _, err = olti_in("compensate", result, targets, "--out", out, "--tables", tables, "--cnc", "heidenhain",
                        expect=2)
    assert "kinematicscomp is a file, not a directory" in err, err
    assert not out.exists() and os.listdir(tables) == ["kinematicscomp"]


@pytest.mark.parametrize("fmt,machine_name", [(f, "trunnion_ac") for f in cnc.FORMATS] +
                         [("heidenhain", "swivel_head_bc"), ("csv", "swivel_head_bc")])
def test_the_names_are_the_files_export_writes(fmt, machine_name, tmp_path):
    m = _machine(machine_name)
    em, x = with_motions(m)
    report = cnc.export(fmt, m, em, x, tmp_path)
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert sorted(cnc.cnc_file_names(fmt, m)) == written
    assert sorted(os.path.relpath(p, tmp_path).replace(os.sep, "/") for p in report.paths) == written
    if fmt == "heidenhain":
        assert len(written) == 6 * len(m.rotary) and f"kinematicscomp/{m.rotary[-1]}_EC{m.rotary[-1]}.COM" in written


def test_an_unknown_format_is_one_line(machine):
    with pytest.raises(InputError, match=r"^--cnc: unknown format 'haas' \(one of sinumerik, fanuc, heidenhain, "
                                         r"linuxcnc, csv\)$"):
        cnc.cnc_file_names("haas", machine)


def test_a_format_that_refuses_the_machine_leaves_nothing(tmp_path):
    """The LinuxCNC module is a table A carrying a table C: on the swivel head (head B, table C) it is refused in
    one line, before COMMANDS.csv is written and without leaving the directories it would have made."""
    path = "olti_drake/models/swivel_head_bc.urdf"
    m = _machine("swivel_head_bc")
    write_five_axis_campaign(tmp_path / "c.csv", distance_campaign(m, synthetic_truth(m, seed=3), 40, 2,
                                                                   SIX_TABLE_STATIONS, "workpiece"))
    olti_in("identify", tmp_path / "c.csv", "--machine", path, "--workpiece-frame", "workpiece", "--tool-frame",
            "tool", "--model", "geometric", "--out", tmp_path / "r.json", expect=0)
    pts, dirs, _, _ = feasible_targets(m, 4, seed=9, a_range=(0.8 * m.lower[3], -5.0))
    targets = write_targets(tmp_path / "t.csv", "x_mm,y_mm,z_mm,i,j,k", [list(p) + list(u) for p, u in zip(pts, dirs)])
    before = sorted(os.listdir(tmp_path))
    _, _, err = olti_in("compensate", tmp_path / "r.json", targets, "--out", tmp_path / "cmd.csv", "--cnc", "linuxcnc",
                        "--tables", tmp_path / "new" / "tables", expect=2)
    assert "linuxcnc: xyzac-trt-kins is a tilting table A" in err and "has head B, table C" in err, err
    assert sorted(os.listdir(tmp_path)) == before  # (no cmd.csv, no new/ nor new/tables/)
    # ... and the CSV tables of the same result are written (a geometric result: its location errors)
    olti_in("compensate", tmp_path / "r.json", targets, "--out", tmp_path / "cmd.csv", "--tables",
            tmp_path / "new" / "tables", expect=0)
    rows = read_rows(tmp_path / "new" / "tables" / "identified.csv")
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["location_errors"] and all(rows[n][0] == pytest.approx(v, rel=1e-12, abs=1e-15)
                                          for n, v in doc["location_errors"].items())
