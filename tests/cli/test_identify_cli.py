"""`olti identify` and `olti predict` as a user runs them (shared/spec/cli.md, formats.md).

Every test runs ``python -m olti_drake.cli`` in a temporary directory on a
campaign simulated once per module (paper-000 default scenario, seed 0).
Units: mm and degrees.
"""

import json

import numpy as np
import pytest

from olti_drake.sim.campaign import prepare, run_campaign, write_campaign
from olti_drake.io.csvio import load_campaign, load_commands
from olti_drake.io.result import load_result
from olti_drake.sim.scenario import Scenario
from olti_calls import error_line, olti_sub


def assert_one_line_error(r, *needles):
    """Exit 2, nothing but one line ``error: ...`` on stderr, mentioning every needle."""
    error_line(r.returncode, r.stderr, *needles)


def read_csv(path):
    """(header, rows as lists of strings), comment lines skipped."""
    lines = [l for l in open(path, encoding="utf-8").read().splitlines() if l.strip() and not l.startswith("#")]
    return lines[0].split(","), [l.split(",") for l in lines[1:]]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A simulated campaign and its error-map identification via the CLI."""
    d = tmp_path_factory.mktemp("identify_cli")
    write_campaign(run_campaign(prepare(Scenario(seed=0))), str(d))
    r = olti_sub("identify", "campaign.csv", "--model", "errormap", "--out", "result.json", cwd=d)
    assert r.returncode == 0, r.stderr
    return d, r


def _numeric_fields(res):
    """The result's values that must not depend on the file layout (line numbers excluded)."""
    keys = ("L1_mm", "L2_mm", "reflectors_mm", "dead_paths_mm", "error_map", "residual_rms_mm", "n_readings",
            "uncertainty", "iterations", "condition_number", "model", "gauge")
    return {k: res[k] for k in keys}


def test_reordered_commented_file_with_invalid_rows_gives_the_same_result(work):
    d, _ = work
    header, rows = read_csv(d / "campaign.csv")
    # Columns in another order, the optional theta4_deg dropped.
    order = ["displacement_mm", "valid", "dir2", "theta2_deg", "reflector", "dir1", "theta1_deg"]
    idx = [header.index(c) for c in order]
    body = [",".join(row[i] for i in idx) for row in rows]
    out = ["# a campaign measured elsewhere", "#", ",".join(order)]
    for k, line in enumerate(body):
        if k % 100 == 50:
            out.append("# operator note: coffee break")
            # A flagged reading: garbage, a NaN and a command outside every grid -- all ignored.
            out.append("nan,0,1,999,1,-1,-999")
            out.append("1e6,0,-1,20,0,1,40")
        out.append(line)
    (d / "reordered.csv").write_text("\n".join(out) + "\n", encoding="utf-8")
    r = olti_sub("identify", "reordered.csv", "--model", "errormap", "--out", "reordered.json", cwd=d)
    assert r.returncode == 0, r.stderr
    a = json.loads((d / "result.json").read_text())
    b = json.loads((d / "reordered.json").read_text())
    assert b["error_map"]["J1"]["grid_deg"] == a["error_map"]["J1"]["grid_deg"]  # 999/-999 did not leak in
    fa, fb = _numeric_fields(a), _numeric_fields(b)
    assert fb["model"] == fa["model"] and fb["gauge"] == fa["gauge"] and fb["n_readings"] == fa["n_readings"]
    for k in ("L1_mm", "L2_mm", "residual_rms_mm", "iterations", "condition_number"):
        assert fb[k] == pytest.approx(fa[k], rel=1e-12, abs=1e-15), k
    for k in ("reflectors_mm", "dead_paths_mm"):
        assert np.asarray(fb[k]) == pytest.approx(np.asarray(fa[k]), rel=1e-12, abs=1e-15), k
    for axis in ("J1", "J2"):
        for key in ("grid_deg", "forward_deg", "reverse_deg"):
            assert np.asarray(fb["error_map"][axis][key]) == pytest.approx(
                np.asarray(fa["error_map"][axis][key]), rel=1e-9, abs=1e-15), (axis, key)
    assert np.asarray(fb["uncertainty"]["reflectors_mm"]) == pytest.approx(
        np.asarray(fa["uncertainty"]["reflectors_mm"]), rel=1e-9)
    # The same readings were used: the original's valid rows.
    assert a["n_readings"] == len(load_campaign(d / "campaign.csv"))


def test_summary_prints_parameters_and_diagnostics(work):
    d, r = work
    res = json.loads((d / "result.json").read_text())
    out = r.stdout
    for needle in ("L1 =", "L2 =", "residual RMS", "iterations", "condition number"):
        assert needle in out, f"{needle!r} missing from summary:\n{out}"
    assert f"L1 = {res['L1_mm']:.4f}" in out and f"L2 = {res['L2_mm']:.4f}" in out
    assert f"residual RMS {1e3 * res['residual_rms_mm']:.2f} um" in out
    assert f"{res['iterations']} iterations" in out
    assert f"condition number {res['condition_number']:.3g}" in out


def _shape(v):
    return np.asarray(v, dtype=float).shape


def test_result_json_follows_formats_md(work):
    d, _ = work
    res = json.loads((d / "result.json").read_text())
    assert res["format"] == "olti-result/1" and res["model"] == "errormap"
    for key in ("L1_mm", "L2_mm", "reflectors_mm", "dead_paths_mm", "error_map", "gauge", "residual_rms_mm",
                "n_readings"):
        assert key in res, key
    assert "theta20_deg" not in res  # absorbed in the J2 map (Table 1)
    assert _shape(res["reflectors_mm"]) == (3, 2) and _shape(res["dead_paths_mm"]) == (3,)
    n = {"J1": 11, "J2": 8}
    for axis in ("J1", "J2"):
        m = res["error_map"][axis]
        assert set(m) == {"grid_deg", "forward_deg", "reverse_deg"}
        assert _shape(m["grid_deg"]) == _shape(m["forward_deg"]) == _shape(m["reverse_deg"]) == (n[axis],)
        assert np.all(np.diff(m["grid_deg"]) > 0)
    # The truth (Scenario: 324.97, 225.004 mm) within 3 reported standard uncertainties (~3 um each); the
    # unidentified nominal 325, 225 mm is ~10 u off and would fail.
    u = res["uncertainty"]
    assert abs(res["L1_mm"] - 324.97) <= 3 * u["L1_mm"] and abs(res["L2_mm"] - 225.004) <= 3 * u["L2_mm"]
    assert abs(325.0 - 324.97) > 3 * u["L1_mm"]
    assert res["n_readings"] == len(load_campaign(d / "campaign.csv"))
    assert 0.010 < res["residual_rms_mm"] < 0.020
    # Uncertainty: same keys and shapes as the values it belongs to, positive, finite.
    u = res["uncertainty"]
    for key in ("L1_mm", "L2_mm", "reflectors_mm", "dead_paths_mm"):
        assert _shape(u[key]) == _shape(res[key]), key
        assert np.all(np.asarray(u[key]) > 0) and np.all(np.isfinite(u[key])), key
    for axis in ("J1", "J2"):
        for key in ("forward_deg", "reverse_deg"):
            assert _shape(u["error_map"][axis][key]) == _shape(res["error_map"][axis][key]), (axis, key)
        assert "grid_deg" not in u["error_map"][axis] or \
            u["error_map"][axis]["grid_deg"] == res["error_map"][axis]["grid_deg"]
    # Gauge: one sentence saying what was fixed and how.
    g = res["gauge"]
    assert isinstance(g, str) and len(g) > 30 and "\n" not in g
    assert "J1" in g and ("rotation" in g or "rotat" in g)


def test_dh_result_has_theta20_and_no_map(work):
    d, _ = work
    r = olti_sub("identify", "campaign.csv", "--model", "dh", "--out", "dh.json", cwd=d)
    assert r.returncode == 0, r.stderr
    assert "theta20" in r.stdout
    res = json.loads((d / "dh.json").read_text())
    assert res["model"] == "dh" and "error_map" not in res
    # D-H cannot represent the continuous truth: its "truth" is what it identifies from the same poses without
    # noise (the estimator's limit). The noisy estimate lies within 3 reported standard uncertainties of it.
    ref = _noise_free_dh()
    u = res["uncertainty"]
    for key in ("theta20_deg", "L1_mm", "L2_mm"):
        assert abs(res[key] - ref.value(key)) <= 3 * u[key], (key, res[key], ref.value(key), u[key])
    assert u["theta20_deg"] < 2e-3  # 1.3 mdeg: a window 15 x narrower than the former +-20 mdeg
    assert _shape(res["uncertainty"]["theta20_deg"]) == ()
    assert res["residual_rms_mm"] > 2 * json.loads((d / "result.json").read_text())["residual_rms_mm"]


def _noise_free_dh():
    """D-H identified from the seed-0 scenario's poses with the reading noise off (numpy twin of the diagram)."""
    import dataclasses

    from olti_drake.model.budget import Budget
    from olti_drake.sim.campaign import simulate_vectorized
    from olti_drake.estimation.identification import IdentificationOptions, identify
    from olti_drake.report.validation import campaign_data

    setup = prepare(Scenario(seed=0))
    quiet = dataclasses.replace(setup, budget=Budget(name="none"))
    return identify(campaign_data(simulate_vectorized(quiet, np.random.default_rng(0))),
                    IdentificationOptions(model="dh"))


def _write_commands(path, rows, order=("theta2_deg", "dir1", "theta1_deg", "dir2")):
    lines = ["# commands to predict", ",".join(order)]
    lines += [",".join(f"{dict(zip(('theta1_deg', 'theta2_deg', 'dir1', 'dir2'), r))[c]:g}" for c in order)
              for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_predict_reproduces_the_model(work):
    d, _ = work
    rows = [(-35.5, 47.25, 1, -1), (0, 0, 1, 1), (60, 140, -1, -1), (-140, 0, 1, 1), (12.3, 99.9, -1, 1)]
    _write_commands(d / "cmd.csv", rows)
    r = olti_sub("predict", "result.json", "cmd.csv", "--out", "pred.csv", cwd=d)
    assert r.returncode == 0, r.stderr
    header, out = read_csv(d / "pred.csv")
    assert set(header) == {"theta1_deg", "theta2_deg", "dir1", "dir2", "x_mm", "y_mm"}
    col = {c: np.array([float(v[header.index(c)]) for v in out]) for c in header}
    cmd, _ = load_commands(d / "cmd.csv")
    for c in ("theta1_deg", "theta2_deg", "dir1", "dir2"):
        assert col[c] == pytest.approx(getattr(cmd, c)), c
    model, _, _, _ = load_result(d / "result.json")
    p = model.positions(cmd)
    assert col["x_mm"] == pytest.approx(p[:, 0], abs=1e-6) and col["y_mm"] == pytest.approx(p[:, 1], abs=1e-6)
    # The map really acts: the prediction differs from the nominal D-H arm by tens of µm.
    t1, t12 = np.radians(cmd.theta1_deg), np.radians(cmd.theta1_deg + cmd.theta2_deg)
    nominal = np.column_stack([model.L1_mm * np.cos(t1) + model.L2_mm * np.cos(t12),
                               model.L1_mm * np.sin(t1) + model.L2_mm * np.sin(t12)])
    assert np.max(np.hypot(*(p - nominal).T)) > 0.02


def test_predict_outside_grid_is_refused_unless_clamped(work):
    d, _ = work
    _write_commands(d / "outside.csv", [(0, 40, 1, 1), (80.5, 20, 1, 1)])
    r = olti_sub("predict", "result.json", "outside.csv", "--out", "out.csv", cwd=d)
    assert_one_line_error(r, "80.5", "J1")
    assert not (d / "out.csv").exists()
    r = olti_sub("predict", "result.json", "outside.csv", "--out", "out.csv", "--outside", "clamp", cwd=d)
    assert r.returncode == 0, r.stderr
    header, out = read_csv(d / "out.csv")
    x = np.array([float(v[header.index("x_mm")]) for v in out])
    model, _, _, _ = load_result(d / "result.json", outside="clamp")
    p = model.positions(load_commands(d / "outside.csv")[0])
    assert x == pytest.approx(p[:, 0], abs=1e-6)
    # Clamped: the J1 deviation beyond the grid is the end node's.
    m1 = model.map1
    assert m1([80.5], 1.0)[0] == pytest.approx(m1.forward_deg[-1])


# -- bad input: exit 2 and one line naming the cause ----------------------------------------------
def _campaign_variant(d, name, edit):
    header, rows = read_csv(d / "campaign.csv")
    header, rows = edit(list(header), [list(r) for r in rows])
    (d / name).write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n", encoding="utf-8")
    return name


def test_missing_column_names_column_and_file(work):
    d, _ = work

    def drop(header, rows):
        k = header.index("dir2")
        return header[:k] + header[k + 1:], [r[:k] + r[k + 1:] for r in rows]

    name = _campaign_variant(d, "nodir2.csv", drop)
    r = olti_sub("identify", name, "--model", "errormap", "--out", "o.json", cwd=d)
    assert_one_line_error(r, "dir2", name)
    assert not (d / "o.json").exists()


def test_nan_in_valid_row_names_line_and_column(work):
    d, _ = work

    def nan(header, rows):
        rows[9][header.index("theta2_deg")] = "nan"  # data row 10 = file line 11 (header on line 1)
        assert rows[9][header.index("valid")] == "1"
        return header, rows

    name = _campaign_variant(d, "nan.csv", nan)
    r = olti_sub("identify", name, "--model", "errormap", "--out", "o.json", cwd=d)
    assert_one_line_error(r, f"{name}:11", "theta2_deg")


def test_reflector_with_two_readings(work):
    d, _ = work

    def thin(header, rows):
        k = header.index("reflector")
        two = [r for r in rows if r[k] == "2"][:2]
        return header, [r for r in rows if r[k] != "2"] + two

    name = _campaign_variant(d, "two.csv", thin)
    r = olti_sub("identify", name, "--model", "errormap", "--out", "o.json", cwd=d)
    assert_one_line_error(r, "reflector 2", "2 valid reading")


def test_one_reflector_only(work):
    d, _ = work

    def one(header, rows):
        k = header.index("reflector")
        return header, [r for r in rows if r[k] == "0"]

    name = _campaign_variant(d, "one.csv", one)
    r = olti_sub("identify", name, "--model", "errormap", "--out", "o.json", cwd=d)
    assert_one_line_error(r, "reflector", "3")


def test_map_node_never_visited(work):
    d, _ = work
    r = olti_sub("identify", "campaign.csv", "--model", "errormap", "--out", "o.json", "--grid1-deg=-140:60:10", cwd=d)
    assert_one_line_error(r, "J1_forward_deg[1]", "not identifiable")


@pytest.mark.parametrize("grid", ["-140:abc:20", "60:-140:20", "0,20,10", "-140:60:30"])
def test_malformed_grid(work, grid):
    d, _ = work
    r = olti_sub("identify", "campaign.csv", "--model", "errormap", "--out", "o.json", f"--grid1-deg={grid}", cwd=d)
    assert_one_line_error(r, "--grid1-deg")


def test_negative_grid_value_as_separate_argument(work):
    """cli.md documents ``--grid1-deg START:STOP:STEP``; a J1 grid naturally starts negative."""
    d, _ = work
    r = olti_sub("identify", "campaign.csv", "--model", "errormap", "--out", "neg.json", "--grid1-deg", "-140:60:20",
                 cwd=d)
    assert r.returncode == 0, r.stderr
    res = json.loads((d / "neg.json").read_text())
    assert res["error_map"]["J1"]["grid_deg"] == list(np.arange(-140.0, 61.0, 20.0))


def test_result_missing_L1(work):
    d, _ = work
    res = json.loads((d / "result.json").read_text())
    del res["L1_mm"]
    (d / "noL1.json").write_text(json.dumps(res), encoding="utf-8")
    _write_commands(d / "cmd_ok.csv", [(0, 40, 1, 1)])
    r = olti_sub("predict", "noL1.json", "cmd_ok.csv", "--out", "p.csv", cwd=d)
    assert_one_line_error(r, "L1_mm", "noL1.json")


# -- trust: refused fits, stated doubts, duplicated readings, the campaign a result came from ------------
def _rewrite(src, dst, change):
    """Copy a campaign CSV, applying ``change(fields) -> fields`` to every data row (comments and header kept)."""
    out, header = [], None
    for line in open(src, encoding="utf-8").read().splitlines():
        if line.startswith("#") or not line.strip():
            out.append(line)
        elif header is None:
            header = line.split(",")
            out.append(line)
        else:
            out.append(",".join(change(dict(zip(header, line.split(",")))).values()))
    dst.write_text("\n".join(out) + "\n", encoding="utf-8")


@pytest.mark.parametrize("case, args, needles", [
    # readings in metres: 100 iterations, condition number inf before
    ("metres", [], ("metres.csv", "refused, nothing written", "did not converge")),
    # L1 = -16737 mm before; a negative nominal length is now refused where the option is read
    ("nominal", ["--nominal-mm=-325,225"], ("--nominal-mm", "-325", "> 0")),
    # converges, but 2x off the stated nominal
    ("nominal2x", ["--nominal-mm", "700,225"], ("campaign.csv", "refused, nothing written", "L1 = 324.97")),
])
def test_untrustworthy_fit_is_refused_one_line_no_file(work, case, args, needles):
    d, _ = work
    campaign = "campaign.csv"
    if case == "metres":
        campaign = "metres.csv"
        _rewrite(d / "campaign.csv", d / campaign,
                 lambda f: dict(f, displacement_mm=f"{float(f['displacement_mm']) / 1000:.12f}"))
    out = d / f"refused_{case}.json"
    r = olti_sub("identify", campaign, "--model", "errormap", "--out", out.name, *args, cwd=d)
    assert_one_line_error(r, *needles)
    assert not out.exists()


def test_physically_impossible_solution_is_named(work):
    from olti_drake.estimation.identification import Identifier

    ident = Identifier(load_campaign(work[0] / "campaign.csv"))
    x = ident.x0.copy()
    assert ident.implausible(x) == []
    x[0], x[3] = -16737.0, 12.0  # L1 negative, a J1 map node beyond 10 deg
    problems = ident.implausible(x)
    assert any("L1 = -16737 mm is not a positive length" in p for p in problems)
    assert any("J1_forward_deg[1] = 12 deg" in p for p in problems)


def test_residual_far_above_the_budget_is_a_stated_warning(work):
    d, _ = work
    res = json.loads((d / "result.json").read_text())
    assert res["warnings"] == [] and ("relative cost" in res["converged"] or "predicted" in res["converged"])
    # A budget of 1 um on the reading: the 15.6 um residual is ~15x what it predicts.
    (d / "tight.yaml").write_text("name: tight\ncontributors:\n- {symbol: u1, value: 1.0, unit: um, "
                                  "k: 1, acts_on: reading}\n", encoding="utf-8")
    r = olti_sub("identify", "campaign.csv", "--model", "errormap", "--out", "tight.json", "--budget", "tight.yaml",
                 cwd=d)
    assert r.returncode == 0, r.stderr
    tight = json.loads((d / "tight.json").read_text())
    ratio = res["residual_rms_mm"] / 1e-3
    residual = [w for w in tight["warnings"] if w.startswith("residual RMS")]
    assert len(residual) == 1 and f"{ratio:.1f} x the reading uncertainty 1.00 um" in residual[0]
    assert "warning: residual RMS" in r.stdout and "'tight'" in r.stdout
    # The under-resolution check is stated in the summary and the result, warning or not.
    check = res["resolution_check"]
    assert check["done"] and 0 < check["ratio"] < 3 and "every second node" in check["method"]
    assert "resolution check: held-out readings" in work[1].stdout


def test_campaign_glued_twice_is_refused_naming_both_lines(work):
    d, _ = work
    text = (d / "campaign.csv").read_text(encoding="utf-8")
    _, rows = read_csv(d / "campaign.csv")
    lines = text.splitlines()
    first_data = next(i for i, l in enumerate(lines) if l and not l.startswith("#")) + 2  # 1-based, after header
    glued = d / "glued.csv"
    glued.write_text(text + "\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8")
    r = olti_sub("identify", glued.name, "--model", "errormap", "--out", "glued.json", cwd=d)
    assert_one_line_error(r, f"glued.csv:{len(lines) + 1}: row identical in every column to line {first_data}")
    assert not (d / "glued.json").exists()
    # A repeated pose with a different reading is a new reading, not a copy.
    _rewrite(d / "campaign.csv", d / "repeat.csv", lambda f: f)
    extra = dict(zip(read_csv(d / "campaign.csv")[0], rows[0]), displacement_mm="0.004924001")
    with open(d / "repeat.csv", "a", encoding="utf-8") as f:
        f.write(",".join(extra.values()) + "\n")
    assert len(load_campaign(d / "repeat.csv")) == len(load_campaign(d / "campaign.csv")) + 1


def test_uncertainty_refuses_another_campaign_and_notes_an_old_result(work):
    d, _ = work
    res = json.loads((d / "result.json").read_text())
    assert res["campaign"]["readings"] == res["n_readings"] and len(res["campaign"]["sha256"]) == 64
    # One reading changed by 1 nm: same count, another digest.
    first = {"done": False}

    def nudge(f):
        if not first["done"] and f["valid"] == "1":
            first["done"] = True
            return dict(f, displacement_mm=f"{float(f['displacement_mm']) + 1e-6:.9f}")
        return f

    _rewrite(d / "campaign.csv", d / "other.csv", nudge)
    r = olti_sub("uncertainty", "result.json", "other.csv", "--method", "linear", "--out", "u_other.json", cwd=d)
    assert_one_line_error(r, "other.csv: not the campaign result.json was identified from",
                          f"{res['n_readings']} valid readings", res["campaign"]["sha256"][:12])
    assert not (d / "u_other.json").exists()
    # A result written before the digest existed: accepted, with a stated note.
    old = {k: v for k, v in res.items() if k != "campaign"}
    (d / "old.json").write_text(json.dumps(old), encoding="utf-8")
    r = olti_sub("uncertainty", "old.json", "campaign.csv", "--method", "linear", "--out", "u_old.json", cwd=d)
    assert r.returncode == 0, r.stderr
    assert "carries no campaign digest" in r.stdout
    assert any("carries no campaign digest" in n for n in json.loads((d / "u_old.json").read_text())["notes"])
