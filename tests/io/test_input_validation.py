"""Every file and option ``olti`` reads is validated where it is read (issue 11, items 4 and 7).

One case per row: a small bad file built in ``tmp_path`` from the shipped data (the paper-000 campaign,
budget, regions, plan) or a bad option value. Each must end with exit status 2 and exactly one line
``error: ...`` naming the file (and line or key) or the option -- no traceback, no solver message
("not identifiable", "SVD did not converge"), and no output file left. The commands run in-process
(``cli.main``; an argparse refusal is its ``SystemExit(2)``), one error-map result identified once.
Units: mm and degrees.
"""

import json
import os

import numpy as np
import pytest

from olti_calls import error_line, olti_in

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.join(ROOT, "data")
CAMPAIGN = os.path.join(DATA, "paper000", "campaign.csv")
BUDGET = os.path.join(DATA, "budget_paper000.yaml")
REGIONS = os.path.join(DATA, "regions_paper000.yaml")
PLAN_YAML = os.path.join(DATA, "plan_paper000.yaml")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """The error-map result of the shipped campaign (one identification per module), its path and dict."""
    from olti_drake.io.csvio import load_campaign
    from olti_drake.estimation.identification import IdentificationOptions, identify
    from olti_drake.io.result import write_result

    path = tmp_path_factory.mktemp("validation") / "result.json"
    write_result(identify(load_campaign(CAMPAIGN), IdentificationOptions(model="errormap")), path)
    return str(path), json.loads(path.read_text())


def assert_refused(argv, capsys, needles, out, solver_words=False):
    """Exit 2, exactly one ``error:`` line naming every needle, no traceback, the output not written;
    unless ``solver_words``, no solver's words (the input was refused before it reached one)."""
    rc, _, err = olti_in(*argv, capsys=capsys)
    assert rc == 2, (rc, err)
    lines = [l for l in err.splitlines() if "error:" in l]
    assert len(lines) == 1 and "Traceback" not in err, err
    if "argument " not in lines[0]:  # argparse's own refusals carry its usage text until cli.main shortens them
        error_line(rc, err)
    for n in needles:
        assert str(n) in lines[0], f"{n!r} not in {lines[0]!r}"
    for bad in ("not identifiable", "SVD", "converge") if not solver_words else ():
        assert bad not in lines[0]
    assert not os.path.exists(out), f"{out} was written"
    return lines[0]


def _lines(path):
    with open(path, encoding="utf-8") as f:
        return f.read().splitlines()


def _write(path, lines):
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return str(path)


def _edit_csv(src, dst, line_no, column, value):
    """Copy CSV ``src`` to ``dst`` with the field ``column`` of 1-based file line ``line_no`` replaced."""
    lines = _lines(src)
    header = next(l for l in lines if not l.startswith("#")).split(",")
    fields = lines[line_no - 1].split(",")
    fields[header.index(column)] = value
    lines[line_no - 1] = ",".join(fields)
    return _write(dst, lines)


def _first_data_line(src):
    lines = _lines(src)
    header = next(i for i, l in enumerate(lines) if not l.startswith("#"))
    return header + 2  # 1-based line of the first data row


# -- item 4: a budget that cannot be right ---------------------------------------------------------------
def _budget_text(edit):
    return edit(open(BUDGET, encoding="utf-8").read())


BUDGET_CASES = {
    "no contributors": (lambda t: "name: empty\ncontributors: []\n", ["no contributors"]),
    "all zero": (lambda t: t.replace("value: 10.0", "value: 0").replace("value: 5.0", "value: 0")
                 .replace("value: 0.04", "value: 0").replace("value: 0.19", "value: 0")
                 .replace("value: 0.09", "value: 0").replace("value: 7.17e-4", "value: 0"), ["every contributor is 0"]),
    "1e300": (lambda t: t.replace("value: 10.0", "value: 1e300", 1), ["contributors[3] (u14)", "1e+300"]),
    "nan": (lambda t: t.replace("value: 0.19", "value: .nan"), ["contributors[1] (u12)", "value"]),
    "inf k": (lambda t: t.replace("value: 0.19, unit: um, k: 1.0", "value: 0.19, unit: um, k: .inf"),
              ["contributors[1] (u12)", "k must be"]),
    "angle 20 deg": (lambda t: t.replace("value: 7.17e-4, unit: rad", "value: 20, unit: deg", 1),
                     ["contributors[7] (u31)", "10 deg"]),
    "2 m length": (lambda t: t.replace("value: 0.04, unit: um", "value: 2, unit: m"), ["contributors[0] (u11)", "1 m"]),
    "distribution": (lambda t: t.replace("acts_on: pose}", "acts_on: pose, distribution: gauss}", 1),
                     ["contributors[3] (u14)", "gauss"]),
    "acts_on": (lambda t: t.replace("acts_on: pose}", "acts_on: tool}", 1), ["contributors[3] (u14)", "tool"]),
    "duplicate key": (lambda t: t.replace("name: paper 000 Table 2", "name: a\nname: b"),
                      [":7:", "duplicate key 'name'"]),
    "duplicate nested key": (lambda t: t.replace("{symbol: u11,", "{symbol: u11, symbol: x,"), [":10:", "'symbol'"]),
}


@pytest.mark.parametrize("case", sorted(BUDGET_CASES))
def test_bad_budget_is_refused_by_uncertainty(case, result, tmp_path, capsys):
    edit, needles = BUDGET_CASES[case]
    budget = tmp_path / "budget.yaml"
    budget.write_text(_budget_text(edit), encoding="utf-8")
    out = tmp_path / "u.json"
    assert_refused(["uncertainty", result[0], CAMPAIGN, "--method", "linear", "--budget", budget, "--out", out],
                   capsys, [str(budget)] + needles, out)


@pytest.mark.parametrize("case", ["no contributors", "all zero", "1e300"])
def test_bad_budget_is_refused_by_design(case, result, tmp_path, capsys):
    """The empty budget used to end in ZeroDivisionError, 1e300 in OverflowError."""
    edit, needles = BUDGET_CASES[case]
    budget = tmp_path / "budget.yaml"
    budget.write_text(_budget_text(edit), encoding="utf-8")
    out = tmp_path / "d.json"
    assert_refused(["design", result[0], "--regions", REGIONS, "--budget", budget, "--out", out], capsys,
                   [str(budget)] + needles, out)


# -- item 7: result.json -------------------------------------------------------------------------------------
def _set(path, value):
    def edit(d):
        *parents, last = path
        for k in parents:
            d = d[k]
        d[last] = value(d[last]) if callable(value) else value
    return edit


RESULT_CASES = {
    "nan length": (_set(["L1_mm"], float("nan")), ["'L1_mm'", "nan"]),
    "negative length": (_set(["L2_mm"], -225.0), ["'L2_mm'", "-225", "> 0"]),
    "absurd length": (_set(["L2_mm"], 1e9), ["'L2_mm'", "1e+09"]),
    "string length": (_set(["L1_mm"], "325"), ["'L1_mm'", "expected a number"]),
    "short forward map": (_set(["error_map", "J1", "forward_deg"], lambda v: v[:-1]),
                          ["'error_map.J1.forward_deg'", "list of 11"]),
    "descending grid": (_set(["error_map", "J2", "grid_deg"], lambda v: v[::-1]),
                        ["'error_map.J2.grid_deg'", "ascending"]),
    "inf in map": (_set(["error_map", "J2", "reverse_deg"], lambda v: v[:3] + [float("inf")] + v[4:]),
                   ["'error_map.J2.reverse_deg'[3]", "inf"]),
    "reflectors N x 3": (_set(["reflectors_mm"], lambda v: [p + [0.0] for p in v]), ["'reflectors_mm'", "N x 2"]),
    "dead paths not N": (_set(["dead_paths_mm"], lambda v: v[:2]), ["'dead_paths_mm'", "list of 3"]),
    "missing J2 map": (lambda d: d["error_map"].pop("J2"), ["'error_map.J2'"]),
    "negative uncertainty": (_set(["uncertainty", "L1_mm"], -1e-3), ["'uncertainty.L1_mm'", "< 0"]),
    "uncertainty shape": (_set(["uncertainty", "reflectors_mm"], [[0.1, 0.1]]), ["'uncertainty.reflectors_mm'"]),
    "machine-tool result": (lambda d: d.update({"format": "olti-multilateration/1"}), ["'format'",
                                                                                       "olti-multilateration/1"]),
    "uncertainty file": (lambda d: d.update({"format": "olti-uncertainty/1"}), ["'format'", "olti-uncertainty/1"]),
}


# `olti uncertainty` takes a machine-tool result too (its own schema: test_bad_machine_result_is_refused).
# `olti report` too, and it reads a machine-tool result by that schema (missing 'targets_mm'); so does
# `olti design` (a 3D machine tool's station design: tests/estimation/test_machine_design.py).
RESULT_VERB_CASES = [(c, v) for c in sorted(RESULT_CASES)
                     for v in ("predict", "compensate", "design", "uncertainty", "report")
                     if not (v in ("uncertainty", "report", "design") and c == "machine-tool result")
                     and not (v == "uncertainty" and c == "uncertainty file")]


@pytest.mark.parametrize("case, verb", RESULT_VERB_CASES)
def test_bad_result_is_refused_naming_the_key(case, verb, result, tmp_path, capsys):
    edit, needles = RESULT_CASES[case]
    data = json.loads(json.dumps(result[1]))
    edit(data)
    bad = tmp_path / "bad_result.json"
    bad.write_text(json.dumps(data))
    out = tmp_path / "out.csv"
    rest = {"predict": [CAMPAIGN, "--out", out], "compensate": [_targets(tmp_path), "--out", out],
            "design": ["--regions", REGIONS, "--out", out],
            "uncertainty": [CAMPAIGN, "--method", "linear", "--out", out], "report": ["--out", out]}[verb]
    assert_refused([verb, bad] + rest, capsys, [str(bad)] + needles, out)


def _targets(tmp_path):
    return _write(tmp_path / "targets.csv", ["x_mm,y_mm", "400,100", "300,-200"])


def test_bad_truth_is_refused_by_report(result, tmp_path, capsys):
    """A truth.json is a result-format file (olti simulate): read with the same schema check."""
    truth = json.load(open(os.path.join(DATA, "paper000", "truth.json"), encoding="utf-8"))
    truth["error_map"]["J1"]["forward_deg"][2] = float("nan")
    bad = tmp_path / "truth.json"
    bad.write_text(json.dumps(truth))
    out = tmp_path / "report"
    assert_refused(["report", result[0], "--truth", bad, "--out", out], capsys,
                   [str(bad), "'error_map.J1.forward_deg'[2]", "nan"], out)


@pytest.mark.parametrize("verb", ["uncertainty", "report"])
def test_a_truth_given_as_result_is_refused_where_an_identification_is_described(verb, tmp_path, capsys):
    truth = os.path.join(DATA, "paper000", "truth.json")
    out = tmp_path / "out"
    argv = [verb, truth, CAMPAIGN, "--method", "linear"] if verb == "uncertainty" else [verb, truth]
    assert_refused(argv + ["--out", out], capsys, [truth, "simulation truth", "--truth"], out)


def test_a_truth_is_a_model_for_predict(tmp_path, capsys):
    """Where only the model is used, truth.json (the result format) predicts the true positions."""
    out = tmp_path / "pred.csv"
    rc, _, err = olti_in("predict", os.path.join(DATA, "paper000", "truth.json"), CAMPAIGN, "--out", out, capsys=capsys)
    assert rc == 0 and out.exists(), err


def test_a_campaign_given_as_result_is_refused(tmp_path, capsys):
    out = tmp_path / "p.csv"
    line = assert_refused(["predict", CAMPAIGN, CAMPAIGN, "--out", out], capsys, [CAMPAIGN, "not valid JSON"], out)
    assert "expected a SCARA result (olti identify)" in line


MACHINE = {"format": "olti-multilateration/1", "targets_mm": [[0, 0], [20, 0], [0, 20], [20, 20]],
           "stations_mm": [[-300, -100], [300, -100], [0, 400]], "dead_paths_mm": [100.0, 110.0, 120.0],
           "gauge": "best-fit", "residual_rms_mm": 0.0}


@pytest.mark.parametrize("key, value, needles", [
    ("targets_mm", [[0, 0], [20, "x"], [0, 20], [20, 20]], ["'targets_mm'"]),
    ("stations_mm", [[-300, -100], [300, float("nan")], [0, 400]], ["'stations_mm'[1, 1]", "nan"]),
    ("dead_paths_mm", [100.0, 110.0], ["'dead_paths_mm'", "list of 3"]),
    ("gauge", None, ["'gauge'"]),
])
def test_bad_machine_result_is_refused(key, value, needles, tmp_path, capsys):
    data = dict(MACHINE, **{key: value})
    bad = tmp_path / "machine.json"
    bad.write_text(json.dumps(data))
    out = tmp_path / "u.json"
    assert_refused(["uncertainty", bad, CAMPAIGN, "--method", "linear", "--out", out], capsys, [str(bad)] + needles,
                   out)


# -- item 7: numeric options ------------------------------------------------------------------------------
def _option_cases():
    ident = ["identify", CAMPAIGN, "--model", "errormap"]
    unc = ["uncertainty", "{result}", CAMPAIGN, "--method", "mc"]
    des = ["design", "{result}", "--regions", REGIONS]
    sim = ["simulate"]
    return [
        (ident, "--huber-k", "0"), (ident, "--huber-k", "-1"), (ident, "--huber-k", "nan"),
        (ident, "--outlier-threshold", "0"), (ident, "--outlier-threshold", "-4"),
        (ident, "--outlier-threshold", "nan"), (ident, "--outlier-threshold", "inf"),
        (ident, "--nominal-mm", "0,225"), (ident, "--nominal-mm", "325,nan"),
        (ident, "--reflectors-mm", "650,0;700,inf;700,100"), (ident, "--reflectors-mm", "1e9,0;1,1;2,2"),
        (ident, "--grid1-deg", "0:60:0"), (ident, "--grid1-deg", "0:60:-10"), (ident, "--grid1-deg", "nan:60:10"),
        (ident, "--grid1-deg", "0:inf:1"), (ident, "--grid1-deg", "-140:60:1e-6"),
        (ident, "--grid2-deg", "0,20,nan"), (ident, "--grid2-deg", "0,1e6"),
        (["multilaterate", CAMPAIGN], "--huber-k", "0"), (["multilaterate", CAMPAIGN], "--stations-mm", "nan,1"),
        (unc, "--trials", "1"), (unc, "--trials", "ten"), (unc, "--k", "0"), (unc, "--k", "nan"),
        (unc, "--coverage", "1"), (unc, "--coverage", "0"), (unc, "--seed", "-1"), (unc, "--seed", "2.5"),
        (unc, "--workers", "0"),
        (des, "--reflectors", "2"), (des, "--step-mm", "0"), (des, "--step-mm", "-50"),
        (des, "--step-mm", "0.001"), (des, "--workspace-step-mm", "0.001"), (des, "--workspace-step-mm", "nan"),
        (des, "--min-separation-mm", "-1"), (des, "--clearance-mm", "inf"), (des, "--base-radius-mm", "-40"),
        (des, "--starts", "0"), (des, "--max-sweeps", "-1"), (des, "--seed", "-3"),
        (sim, "--seed", "-1"), (sim + ["--meshcat"], "--meshcat-port", "0"),
        (sim + ["--meshcat"], "--meshcat-port", "70000"), (sim, "--error-scale", "-500"),
        (sim, "--error-scale", "0"), (sim, "--realtime-rate", "-1"), (sim, "--realtime-rate", "nan"),
    ]


@pytest.mark.parametrize("argv, option, value", _option_cases(),
                         ids=[f"{a[0]} {o} {v}" for a, o, v in _option_cases()])
def test_bad_numeric_option_is_refused_naming_it(argv, option, value, result, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [a.format(result=result[0]) for a in argv] + [f"{option}={value}", "--out", out]
    assert_refused(argv, capsys, [option], out)


# -- item 7: YAML files ----------------------------------------------------------------------------------
def test_duplicate_keys_are_refused_in_every_yaml(result, tmp_path, capsys):
    regions = _write(tmp_path / "regions.yaml", ["regions:", "  - name: a", "    x_mm: [650, 900]",
                                                 "    y_mm: [-900, 350]", "    x_mm: [0, 1]"])
    out = tmp_path / "d.json"
    assert_refused(["design", result[0], "--regions", regions, "--out", out], capsys,
                   [f"{regions}:5:", "duplicate key 'x_mm'", "first on line 3"], out)
    plan = _write(tmp_path / "plan.yaml", _lines(PLAN_YAML) + ["theta1_step: 10.0"])
    assert_refused(["design", result[0], "--regions", REGIONS, "--plan", plan, "--out", out], capsys,
                   [plan, "duplicate key 'theta1_step'"], out)
    scenario = _write(tmp_path / "scenario.yaml", ["seed: 1", "station: !Emulated {speed: fast, speed: realistic}"])
    out_dir = tmp_path / "sim"
    assert_refused(["simulate", scenario, "--out", out_dir], capsys, [f"{scenario}:2:", "duplicate key 'speed'"],
                   out_dir)


# -- item 7: text that is not UTF-8 -----------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["campaign", "budget", "regions", "scenario", "result", "targets"])
def test_non_utf8_bytes_are_refused_naming_file_and_line(kind, result, tmp_path, capsys):
    src = {"campaign": CAMPAIGN, "budget": BUDGET, "regions": REGIONS, "result": result[0],
           "scenario": os.path.join(ROOT, "diagrams", "paper000_scara.yaml"), "targets": _targets(tmp_path)}[kind]
    raw = open(src, "rb").read().split(b"\n")
    raw[2] += b" \xe9"  # Latin-1 'é' on line 3
    bad = tmp_path / ("bad" + os.path.splitext(src)[1])
    bad.write_bytes(b"\n".join(raw))
    out = tmp_path / "out"
    argv = {"campaign": ["identify", bad, "--model", "dh"],
            "budget": ["uncertainty", result[0], CAMPAIGN, "--method", "linear", "--budget", bad],
            "regions": ["design", result[0], "--regions", bad],
            "scenario": ["simulate", bad],
            "result": ["predict", bad, CAMPAIGN],
            "targets": ["compensate", result[0], bad]}[kind]
    assert_refused(argv + ["--out", out], capsys, [f"{bad}:3:", "not UTF-8", "0xe9"], out)


# -- item 7: readings, commands and targets far outside any physical range ------------------------------
CSV_CASES = [
    # (verb, file to edit, column, value, needle)
    ("identify", "campaign", "theta1_deg", "1e6", "720 deg"),
    ("identify", "campaign", "theta2_deg", "-800", "720 deg"),
    ("identify", "campaign", "displacement_mm", "2e5", "100000 mm"),
    ("identify", "campaign", "displacement_mm", "inf", "not finite"),
    ("identify", "campaign", "theta2_deg", "nan", "not finite"),
    ("identify", "campaign", "dir1", "3", "not one of -1, 1"),
    ("identify", "campaign", "dir2", "0.5", "not a whole number"),
    ("identify", "campaign", "reflector", "-1", "index"),
    ("predict", "commands", "theta1_deg", "1e4", "720 deg"),
    ("predict", "commands", "dir2", "0", "not one of -1, 1"),
    ("compensate", "targets", "x_mm", "1e6", "100000 mm"),
    ("design", "plan", "theta2_deg", "3600", "720 deg"),
    ("multilaterate", "machine", "x_cmd_mm", "1e6", "100000 mm"),
    ("multilaterate", "machine", "displacement_mm", "nan", "not finite"),
]


def _machine_campaign(tmp_path):
    rows = ["station,target,x_cmd_mm,y_cmd_mm,displacement_mm"]
    rows += [f"{j},{i},{20 * (i % 2)},{20 * (i // 2)},{0.1 * i + j}" for j in range(3) for i in range(4)]
    return _write(tmp_path / "machine.csv", rows)


@pytest.mark.parametrize("verb, kind, column, value, needle", CSV_CASES,
                         ids=[f"{c[1]} {c[2]}={c[3]}" for c in CSV_CASES])
def test_values_outside_any_physical_range_name_file_line_column(verb, kind, column, value, needle, result,
                                                                 tmp_path, capsys):
    src = {"campaign": CAMPAIGN, "commands": CAMPAIGN, "targets": _targets(tmp_path),
           "plan": os.path.join(DATA, "plan_paper000.csv"), "machine": _machine_campaign(tmp_path)}[kind]
    line = _first_data_line(src) + 1
    bad = _edit_csv(src, tmp_path / f"bad_{kind}.csv", line, column, value)
    out = tmp_path / "out.json"
    argv = {"identify": ["identify", bad, "--model", "errormap"], "predict": ["predict", result[0], bad],
            "compensate": ["compensate", result[0], bad],
            "design": ["design", result[0], "--regions", REGIONS, "--plan", bad],
            "multilaterate": ["multilaterate", bad]}[verb]
    assert_refused(argv + ["--out", out], capsys, [f"{bad}:{line}:", f"'{column}'", needle], out)


def test_a_reading_far_from_its_reflectors_others_is_named_before_the_solver(tmp_path, capsys):
    """99999 mm is within the +-100 m bound, but no SCARA moves a reflector's distance by that much: it
    used to end as "not identifiable: P0_x_mm, P0_y_mm, d0_0_mm"."""
    line = _first_data_line(CAMPAIGN) + 10
    bad = _edit_csv(CAMPAIGN, tmp_path / "bad.csv", line, "displacement_mm", "99999")
    out = tmp_path / "r.json"
    for model in ("errormap", "dh"):
        assert_refused(["identify", bad, "--model", model, "--out", out], capsys,
                       [f"{bad}:{line}:", "'displacement_mm'", "median of reflector 0", "4000 mm"], out)
    machine = _machine_campaign(tmp_path)
    line = _first_data_line(machine) + 5
    bad = _edit_csv(machine, tmp_path / "bad_machine.csv", line, "displacement_mm", "500")
    assert_refused(["multilaterate", bad, "--out", out], capsys, [f"{bad}:{line}:", "median of station 1"], out)


def test_an_unidentifiable_map_node_names_the_lines_commanding_it(tmp_path, capsys):
    """A mistyped angle within +-720 deg makes its own default-grid node: the error names its line."""
    line = _first_data_line(CAMPAIGN) + 10
    bad = _edit_csv(CAMPAIGN, tmp_path / "bad.csv", line, "theta1_deg", "700")
    out = tmp_path / "r.json"
    msg = assert_refused(["identify", bad, "--model", "errormap", "--out", out], capsys,
                         ["J1_reverse_deg[11]", "node 700 deg", f"{bad}:{line} ", "check that command"], out,
                         solver_words=True)
    assert msg.count(f"{bad}:") == 1


def test_physical_bounds_are_stated_and_shared():
    """One table of bounds (olti_drake.units.UNIT_BOUNDS) serves CSV columns, JSON keys and the CLI's lengths."""
    from olti_drake.cli import args as cliargs
    from olti_drake.units import unit_bound

    assert unit_bound("theta1_deg") == 720.0 and unit_bound("x_cmd_mm") == 1e5 and unit_bound("dir1") == np.inf
    assert cliargs.MAX_MM == unit_bound("_mm")


def test_yaml_reader_accepts_repeated_keys_in_different_mappings_and_tags(tmp_path):
    """Only a key given twice in ONE mapping is refused: sibling mappings, nested tags and a BOM are fine."""
    from olti_drake.errors import InputError
    from olti_drake.io.csvio import read_yaml

    ok = tmp_path / "ok.yaml"
    ok.write_bytes("\ufeffa: 1\nlist:\n- {name: x, v: 1}\n- {name: y, v: 2}\nstation: !Emulated {speed: fast}\n"
                   "nested: {a: {a: 1}}\n".encode("utf-8"))
    assert read_yaml(ok) == {"a": 1, "list": [{"name": "x", "v": 1}, {"name": "y", "v": 2}],
                             "station": {"speed": "fast"}, "nested": {"a": {"a": 1}}}
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: 1\nlist:\n- {name: x, v: 1}\n- name: y\n  v: 2\n  name: z\n")
    with pytest.raises(InputError, match=r"bad.yaml:6: duplicate key 'name' \(first on line 4\)"):
        read_yaml(bad)
    bad.write_text("a: [1, 2\n")
    with pytest.raises(InputError, match=r"bad.yaml:2: not valid YAML"):
        read_yaml(bad)


def test_generated_plans_regions_and_default_grids_are_capped(result, tmp_path, capsys):
    """Steps in the wrong unit would allocate gigabytes: refused, naming the step or the option."""
    out = tmp_path / "d.json"
    plan = _write(tmp_path / "plan.yaml", ["theta1_start: -140.0", "theta1_stop: 60.0", "theta1_step: 1e-6"])
    assert_refused(["design", result[0], "--regions", REGIONS, "--plan", plan, "--out", out], capsys,
                   [plan, "theta1_step", "1,000,000"], out)
    plan = _write(tmp_path / "plan2.yaml", ["theta1_step: 0.1", "theta2_step: 0.01"])
    assert_refused(["design", result[0], "--regions", REGIONS, "--plan", plan, "--out", out], capsys,
                   [plan, "theta2_step", "poses"], out)
    regions = _write(tmp_path / "regions.yaml", ["regions:", "  - {x_mm: [650, 1e9], y_mm: [0, 100]}"])
    assert_refused(["design", result[0], "--regions", regions, "--out", out], capsys,
                   [regions, "regions[0].x_mm", "100000 mm"], out)
    # A campaign of random poses: every command distinct, so the default grid would have thousands of nodes.
    rng = np.random.default_rng(0)
    rows = ["reflector,theta1_deg,theta2_deg,dir1,dir2,displacement_mm"]
    rows += [f"{i % 3},{t1:.6f},{t2:.6f},1,1,{d:.6f}" for i, (t1, t2, d) in
             enumerate(zip(rng.uniform(-140, 60, 2500), rng.uniform(0, 140, 2500), rng.uniform(-100, 100, 2500)))]
    campaign = _write(tmp_path / "random.csv", rows)
    out = tmp_path / "r.json"
    assert_refused(["identify", campaign, "--model", "errormap", "--out", out], capsys,
                   [campaign, "distinct J1 commands", "--grid1-deg"], out)
