"""Tracker exports in (olti import-points; issue 26, item 2): a simulated six-axis tracker campaign of the UR5 (the
truth's joint deviations outside the identified model's family) written as the tracker software would export it --
a SpatialAnalyzer-style ASCII point list in metres with a reference point the log does not have, and a column-mapped
CSV with its own point names, ISO time stamps off by up to 0.2 s, both with shuffled rows -- imported against the
robot's joint log (by name, by time); identifying either import equals identifying the original campaign (every
parameter within 1e-6 mm / deg). Bad input is refused in one line naming the file and line."""

import os
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import load_serial_result, read_serial_campaign, write_serial_campaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import synthetic_campaign, synthetic_truth
from olti_calls import error_line

UR5 = os.path.join(PACKAGE_DIR, "models", "ur5.urdf")
N = 80
T0 = datetime(2026, 12, 2, 9, 0, 0, tzinfo=timezone.utc)


def _log(path, camp, names, times, rows=None):
    rows = np.arange(N) if rows is None else rows
    head = ",".join([f"theta{i}_deg" for i in range(1, 7)] + [f"dir{i}" for i in range(1, 7)] + ["name", "time_s"])
    lines = [head] + [",".join([f"{v:.12g}" for v in camp.commands[k]] + [f"{int(v)}" for v in camp.dirs[k]]
                               + [names[k], f"{times[k]:.3f}"]) for k in rows]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("track")
    truth = synthetic_truth(load_serial_chain(UR5, "tool0"), seed=6, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, N, seed=6, noise_mm=0.002)
    write_serial_campaign(d / "original.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    pts = read_serial_campaign(d / "original.csv").points_mm  # (the values as the campaign file holds them)
    rng = np.random.default_rng(3)
    names = [f"P{k + 1:03d}" for k in range(N)]
    times = 30.0 + 7.5 * np.arange(N)
    _log(d / "log.csv", camp, names, times)
    shuffled = rng.permutation(N)
    sa = ["// SpatialAnalyzer export, frame: Tracker", "// Units: Meters"]
    sa += [f"Robot Cal {names[k]} {pts[k, 0] / 1e3:.15e} {pts[k, 1] / 1e3:.15e} {pts[k, 2] / 1e3:.15e}"
           for k in shuffled]
    sa.insert(7, "Robot Ref NEST1 1.0 2.0 0.5")  # (a reference nest: no row of the log)
    (d / "export.txt").write_text("\n".join(sa) + "\n")
    jitter = rng.uniform(-0.2, 0.2, N)
    csv = ["Point;X;Y;Z;Timestamp"] + [
        f"T{k};{pts[k, 0]:.9f};{pts[k, 1]:.9f};{pts[k, 2]:.9f};"
        f"{(T0 + timedelta(seconds=times[k] + jitter[k])).isoformat()}" for k in shuffled]
    (d / "export.csv").write_text("\n".join(csv) + "\n")
    iso = [(T0 + timedelta(seconds=t)).isoformat() for t in times]
    _log(d / "log_iso.csv", camp, names, times)
    text = (d / "log_iso.csv").read_text().replace(",time_s", ",timestamp")
    (d / "log_iso.csv").write_text("\n".join([text.splitlines()[0]] + [
        line.rsplit(",", 1)[0] + "," + iso[k] for k, line in enumerate(text.splitlines()[1:])]) + "\n")
    assert main(["import-points", str(d / "export.txt"), "--joints", str(d / "log.csv"), "--out",
                 str(d / "from_sa.csv")]) == 0
    assert main(["import-points", str(d / "export.csv"), "--joints", str(d / "log_iso.csv"), "--out",
                 str(d / "from_csv.csv"), "--columns", "name=Point,x=X,y=Y,z=Z,time=Timestamp", "--match", "time",
                 "--max-dt-s", "0.5"]) == 0
    for name in ("original", "from_sa", "from_csv"):
        assert main(["identify", str(d / f"{name}.csv"), "--robot", "ur5", "--tool-frame", "tool0",
                     "--tool-offset-mm", "40,-25,60", "--model", "dh", "--out", str(d / f"{name}.json")]) == 0
    return d


@pytest.mark.parametrize("name", ["from_sa", "from_csv"])
def test_an_imported_export_identifies_as_the_original_campaign(files, name):
    orig, imp = read_serial_campaign(files / "original.csv"), read_serial_campaign(files / f"{name}.csv")
    assert np.array_equal(imp.commands, orig.commands) and np.array_equal(imp.dirs, orig.dirs)
    assert np.abs(imp.points_mm - orig.points_mm).max() < 1e-8  # (metres at 15 digits -> mm)
    a, b = load_serial_result(files / "original.json"), load_serial_result(files / f"{name}.json")
    assert a.model.names == b.model.names
    assert np.abs(a.x - b.x).max() < 1e-6


def test_the_campaign_names_its_sources_and_what_was_skipped(files, capsys):
    import hashlib

    text = (files / "from_sa.csv").read_text()
    for src in ("export.txt", "log.csv"):
        assert hashlib.sha256((files / src).read_bytes()).hexdigest() in text
    assert "units m from the export's header (line 2)" in text and "skipped 1 export point(s)" in text
    # a log row the tracker missed is skipped and named by its line
    lines = (files / "log.csv").read_text().splitlines()
    (files / "log_more.csv").write_text("\n".join(lines + [lines[1].replace("P001", "P999")]) + "\n")
    capsys.readouterr()
    assert main(["import-points", str(files / "export.txt"), "--joints", str(files / "log_more.csv"), "--out",
                 str(files / "more.csv")]) == 0
    out = capsys.readouterr().out
    assert f"skipped 1 log row(s) without a point: {files / 'log_more.csv'} line(s) {N + 2}" in out


def _refusal(files, capsys, export_text, args=(), joints="log.csv", suffix=".txt"):
    capsys.readouterr()
    path = files / f"bad{suffix}"
    path.write_text(export_text)
    out = files / "refused.csv"
    code = main(["import-points", str(path), "--joints", str(files / joints), "--out", str(out), *args])
    err = capsys.readouterr().err
    error_line(code, err)
    assert not out.exists()
    return err


def test_bad_input_is_refused_in_one_line_naming_file_and_line(files, capsys):
    good = (files / "export.txt").read_text().splitlines()
    bad = good[:4] + [good[4].rsplit(" ", 1)[0] + " 0.12.5"] + good[5:]
    assert "bad.txt:5: Z: '0.12.5' is not a number" in _refusal(files, capsys, "\n".join(bad))
    dup = good + [good[3]]
    assert f"bad.txt:{len(dup)}: duplicate point name" in _refusal(files, capsys, "\n".join(dup))
    units = [good[0], "// Units: Furlongs"] + good[2:]
    assert "bad.txt:2: unknown units 'Furlongs'" in _refusal(files, capsys, "\n".join(units))
    assert "says units m, --units says mm" in _refusal(files, capsys, "\n".join(good), ["--units", "mm"])
    csv = (files / "export.csv").read_text()
    assert "bad.csv:1: missing column 'Q'" in _refusal(files, capsys, csv, ["--columns", "x=Q"], suffix=".csv")
    assert "no point matches a row" in _refusal(files, capsys, csv, [
        "--columns", "name=Point,x=X,y=Y,z=Z,time=Timestamp", "--match", "time", "--max-dt-s", "1e-6"],
        joints="log_iso.csv", suffix=".csv")
    assert "no point matches a row" in _refusal(files, capsys, csv, ["--columns", "name=Point,x=X,y=Y,z=Z"],
                                                joints="log_iso.csv", suffix=".csv")
    lines = (files / "log.csv").read_text().splitlines()
    (files / "log_dup.csv").write_text("\n".join(lines + [lines[2].replace("P002", "P001")]) + "\n")
    assert f"log_dup.csv:{N + 2}: duplicate 'name' 'P001' (first on line 2)" in _refusal(
        files, capsys, "\n".join(good), joints="log_dup.csv")
    # never over an input
    capsys.readouterr()
    assert main(["import-points", str(files / "export.txt"), "--joints", str(files / "log.csv"), "--out",
                 str(files / "log.csv")]) != 0
    assert "would overwrite an input" in capsys.readouterr().err


def test_sa_name_forms_and_separators_read_alike(files):
    """SA's one-token Collection::Group::Target names, comma separated, in mm (stated by --units, no header): the
    same campaign as the space-separated metre export."""
    lines = [ln.split() for ln in (files / "export.txt").read_text().splitlines() if not ln.startswith("//")]
    (files / "export_mm.txt").write_text("\n".join(
        f"{a}::{b}::{c}, " + ", ".join(f"{1e3 * float(v):.12f}" for v in xyz) for a, b, c, *xyz in lines) + "\n")
    assert main(["import-points", str(files / "export_mm.txt"), "--joints", str(files / "log.csv"), "--out",
                 str(files / "from_sa_mm.csv"), "--units", "mm", "--format", "sa"]) == 0
    a, b = (read_serial_campaign(files / n) for n in ("from_sa.csv", "from_sa_mm.csv"))
    assert np.array_equal(a.commands, b.commands) and np.abs(a.points_mm - b.points_mm).max() < 1e-8
    assert "units mm from --units" in (files / "from_sa_mm.csv").read_text()
