"""One registry of kinds, one result document, one route per verb (issue 22, item 2).

* Every result document names its format and its ``kind`` (olti_drake.formats, io.documents); a result written
  before the ``kind`` key (the three format ids, a ``robot`` object telling a serial robot's) still loads in
  ``predict``, ``uncertainty``, ``report``, ``compensate`` and ``design`` -- with the same outputs as the file
  with its kind; an unknown kind or format is refused in one line naming the file.
* ``olti identify`` (all four kinds, ``olti multilaterate`` included) is one route, campaign CSV ->
  calibration_problem -> fit -> document -> written: its results equal (numbers within tolerance, never bytes)
  those of the library calls today's verbs made.
* The kind is asked in the registries only: no ``isinstance(raw.get("robot"), dict)``, no ``["format"] ==``, no
  ``hasattr(setup, "n_joints")``, no format id spelled outside ``olti_drake/formats.py`` (read with ``ast``).
* Options that do not apply to a kind are refused by the one table (cli/kinds.py), whose "not given" values are
  the parser's defaults.
"""

import ast
import json
import re
from pathlib import Path

import numpy as np
import pytest

from numeric_files import json_differences
from olti_drake.cli.verbs import build_parser, main
from olti_drake.errors import InputError
from olti_drake.io.documents import read_result, result_kind, with_kind
from olti_calls import error_line, olti_in

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "olti_drake"
PAPER = ROOT / "data" / "paper000" / "campaign.csv"
SCARA_REGIONS = ROOT / "data" / "regions_paper000.yaml"
TOOL = (40.0, -25.0, 60.0)
TOOLS = ((0.0, 0.0, 100.0), (150.0, 0.0, 100.0), (0.0, 150.0, 140.0))
TOOLS_ARG = ";".join(",".join(str(v) for v in t) for t in TOOLS)
MACHINE_REGIONS = ("regions:\n  - {x_mm: [-400, -200], y_mm: [-300, 600], z_mm: [0, 400]}\n"
                   "  - {x_mm: [600, 800], y_mm: [-300, 600], z_mm: [0, 400]}\n"
                   "  - {x_mm: [0, 400], y_mm: [-400, -300], z_mm: [0, 400]}\n")
FLOOR_REGIONS = "regions:\n  - {x_mm: [-1500, 1500], y_mm: [-1500, 1500], z_mm: -400}\n"


# -- the campaigns and the results of every kind -----------------------------------------------------------------
@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    """A six-axis distance campaign (4 stations), a 3D machine campaign of 3 tools (volumetric) and one of one tool
    on a small grid (multilateration), seeded; the SCARA's is the shipped paper campaign."""
    from olti_drake.io.csvio import write_machine_campaign
    from olti_drake.io.serial_io import load_robot, write_serial_campaign
    from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d
    from olti_drake.model.serial import synthetic_campaign, synthetic_truth
    from olti_drake.model.volumetric3d import MachineConfig

    d = tmp_path_factory.mktemp("campaigns")
    chain = load_robot("ur5", "tool0")
    camp = synthetic_campaign(synthetic_truth(chain, seed=3, tool_offset_mm=TOOL), 150, seed=4, noise_mm=1e-3)
    write_serial_campaign(d / "serial.csv", camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    cfg = MachineConfig(tool_offsets_mm=TOOLS, knot_spacing_mm=100.0)
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(3, 3, 3), tools=(0,), seed=4))
    write_machine_campaign(cols, d / "multilateration.csv")
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(5, 4, 4), tools=(0, 1, 2), seed=4))
    write_machine_campaign(cols, d / "volumetric.csv")
    return {"scara": PAPER, "serial": d / "serial.csv", "multilateration": d / "multilateration.csv",
            "volumetric": d / "volumetric.csv", "chain": chain}


IDENTIFY = {
    "scara": lambda c: ["identify", c["scara"], "--model", "errormap"],
    "serial": lambda c: ["identify", c["serial"], "--model", "errormap", "--robot", "ur5", "--tool-frame", "tool0",
                         "--tool-offset-mm", "40,-25,60", "--grid-step-deg", "30"],
    "multilateration": lambda c: ["multilaterate", c["multilateration"]],
    "volumetric": lambda c: ["identify", c["volumetric"], "--model", "volumetric", "--tool-offsets-mm", TOOLS_ARG],
}


@pytest.fixture(scope="module")
def results(campaigns, tmp_path_factory):
    """{kind: (path of the result written by the CLI now, its document)}."""
    out = {}
    for kind, argv in IDENTIFY.items():
        path = tmp_path_factory.mktemp(kind) / "result.json"
        assert main([str(a) for a in argv(campaigns)] + ["--out", str(path)]) == 0
        out[kind] = (path, json.loads(path.read_text()))
    return out


# -- the document -------------------------------------------------------------------------------------------------
def test_every_result_names_its_kind_first_and_keeps_the_keys_the_spec_requires(results):
    required = {"scara": ("model", "L1_mm", "L2_mm", "reflectors_mm", "dead_paths_mm", "error_map", "gauge",
                          "residual_rms_mm", "n_readings"),
                "serial": ("model", "robot", "gauge", "residual_rms_mm", "n_readings", "uncertainty", "error_map",
                           "tool_offset_mm", "stations_mm", "dead_paths_mm"),
                "multilateration": ("targets_mm", "stations_mm", "dead_paths_mm", "gauge", "residual_rms_mm"),
                "volumetric": ("error_motions", "squareness_urad", "tool_offsets_mm", "stations_mm", "dead_paths_mm",
                               "gauge", "uncertainty")}
    formats = {"scara": "olti-result/1", "serial": "olti-result/1", "multilateration": "olti-multilateration/1",
               "volumetric": "olti-volumetric/1"}
    for kind, (path, doc) in results.items():
        assert list(doc)[:2] == ["format", "kind"] and doc["format"] == formats[kind] and doc["kind"] == kind
        assert all(k in doc for k in required[kind]), kind
        assert read_result(path) == (kind, doc)


def test_the_kind_of_a_document_written_before_the_kind_key_is_inferred_as_then():
    assert result_kind({"format": "olti-result/1", "model": "dh"}, "r.json") == "scara"
    assert result_kind({"format": "olti-result/1", "robot": {"file": "ur5"}}, "r.json") == "serial"
    assert result_kind({"format": "olti-result/1", "robot": "ur5"}, "r.json") == "scara"  # (as then: an object)
    assert result_kind({"format": "olti-multilateration/1"}, "r.json") == "multilateration"
    assert result_kind({"format": "olti-volumetric/1"}, "r.json") == "volumetric"
    # the kind key wins over the robot object; format and kind first, the rest in order
    assert result_kind({"format": "olti-result/1", "kind": "scara", "robot": {}}, "r.json") == "scara"
    assert list(with_kind("serial", {"model": "dh", "format": "olti-result/1", "gauge": "g"})) == [
        "format", "kind", "model", "gauge"]
    with pytest.raises(ValueError, match="olti-volumetric/1"):
        with_kind("volumetric", {"format": "olti-result/1"})


@pytest.mark.parametrize("doc, needles", [
    ({"format": "olti-result/1", "kind": "spline"}, ["key 'kind'", "unknown result kind 'spline'"]),
    ({"format": "olti-foo/1"}, ["'format' must be", "'olti-foo/1'"]),
    ({"kind": "scara"}, ["'format' must be", "got None"]),
    ({"format": "olti-volumetric/1", "kind": "scara"}, ["key 'kind' 'scara' does not go with 'format'"]),
    ({"format": "olti-uncertainty/1", "k": 1}, ["'format' must be", "olti-uncertainty/1"]),
])
def test_an_unknown_kind_or_format_is_refused_in_one_line_naming_the_file(doc, needles, results, campaigns,
                                                                          tmp_path, capsys):
    bad = tmp_path / "odd.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        read_result(bad)
    assert str(bad) in str(e.value) and "\n" not in str(e.value)
    out = tmp_path / "out"
    for argv in (["predict", bad, PAPER, "--out", out], ["compensate", bad, PAPER, "--out", out],
                 ["uncertainty", bad, PAPER, "--method", "linear", "--out", out],
                 ["design", bad, "--regions", SCARA_REGIONS, "--out", out], ["report", bad, "--out", out]):
        code, _, err = olti_in(*argv, capsys=capsys)
        error_line(code, err, bad, *needles)
        assert not out.exists()


def test_a_verb_refuses_a_kind_it_does_not_take_naming_file_kind_and_what_it_takes(results, capsys, tmp_path):
    ml, vol = results["multilateration"][0], results["volumetric"][0]
    code, _, err = olti_in("predict", ml, PAPER, "--out", tmp_path / "p.csv", capsys=capsys)
    error_line(code, err, ml, "multilateration result", "'format' 'olti-multilateration/1'",
                   "olti predict takes SCARA, serial-robot, volumetric and five-axis machine results")
    code, _, err = olti_in("compensate", ml, PAPER, "--out", tmp_path / "p.csv", capsys=capsys)
    error_line(code, err, ml, "olti compensate takes")
    # (olti uncertainty takes a volumetric result now: with the SCARA's campaign it is that file refused, by name)
    code, _, err = olti_in("uncertainty", vol, PAPER, "--method", "linear", "--out", tmp_path / "u.json", capsys=capsys)
    error_line(code, err, PAPER, "missing required column 'station'")
    assert not (tmp_path / "u.json").exists()


# -- old result files still load in every verb -------------------------------------------------------------------
def _legacy(path: Path, doc: dict, where: Path) -> Path:
    """``doc`` as today's version wrote it (no ``kind`` key) at ``where/result.json``."""
    where.mkdir(parents=True, exist_ok=True)
    old = dict(doc)
    del old["kind"]
    (where / "result.json").write_text(json.dumps(old, indent=1))
    return where / "result.json"


def _inputs(kind, campaigns, d: Path) -> dict:
    """The per-verb arguments after RESULT (``{d}``: the directory of the run)."""
    from olti_drake.io.csvio import write_table

    if kind == "scara":
        (d / "targets.csv").write_text("x_mm,y_mm\n400,100\n300,-200\n")
        return {"predict": [PAPER], "compensate": [d / "targets.csv"],
                "uncertainty": [PAPER, "--method", "linear"],
                "design": ["--regions", SCARA_REGIONS, "--step-mm", "150", "--workspace-step-mm", "100",
                           "--starts", "1", "--max-sweeps", "1"],
                "report": ["--campaign", PAPER]}
    if kind == "serial":
        chain = campaigns["chain"]
        poses = chain.random_angles(5, seed=21) * 0.5  # (away from the stretched elbow: reachable)
        dirs = np.ones_like(poses)
        t = chain.positions(poses, chain.nominal_parameters(TOOL))
        cols = {"x_mm": t[:, 0], "y_mm": t[:, 1], "z_mm": t[:, 2]}
        cols.update({f"theta{i + 1}_deg": poses[:, i] for i in range(6)})
        cols.update({f"dir{i + 1}": dirs[:, i] for i in range(6)})
        write_table(d / "targets.csv", cols, {f"dir{i + 1}": "%d" for i in range(6)})
        (d / "floor.yaml").write_text(FLOOR_REGIONS)
        return {"predict": [campaigns["serial"]], "compensate": [d / "targets.csv"],
                "uncertainty": [campaigns["serial"], "--method", "linear", "--workspace-poses", "20"],
                "design": ["--regions", d / "floor.yaml", "--step-mm", "1500", "--starts", "1", "--max-sweeps", "1",
                           "--workspace-poses", "20"],
                "report": ["--campaign", campaigns["serial"]]}
    (d / "regions.yaml").write_text(MACHINE_REGIONS)
    design = ["--regions", d / "regions.yaml", "--stations", "5", "--step-mm", "300", "--starts", "1",
              "--max-sweeps", "1"]
    if kind == "multilateration":
        return {"uncertainty": [campaigns["multilateration"], "--method", "linear"], "design": design,
                "report": ["--campaign", campaigns["multilateration"]]}
    (d / "points.csv").write_text("x_cmd_mm,y_cmd_mm,z_cmd_mm,tool\n100,100,100,0\n200,150,50,1\n")
    (d / "wanted.csv").write_text("x_mm,y_mm,z_mm,tool\n100,100,200,0\n300,150,150,1\n")
    return {"predict": [d / "points.csv"], "compensate": [d / "wanted.csv"], "design": design,
            "report": ["--campaign", campaigns["volumetric"]]}


def _output(verb, d: Path) -> Path:
    return d / {"predict": "pred.csv", "compensate": "commands.csv", "uncertainty": "unc.json",
                "design": "design.json", "report": "rep"}[verb]


def _comparable(path: Path, d: Path):
    """An output with the run's directory and its timings taken out."""
    if path.is_dir():
        return sorted(p.name for p in path.iterdir())
    text = path.read_text().replace(str(d), "<run>")
    if path.suffix == ".json":
        doc = json.loads(text)
        doc.pop("elapsed_s", None)
        return doc
    return text


@pytest.mark.parametrize("kind", ["scara", "serial", "multilateration", "volumetric"])
def test_an_old_result_file_loads_in_every_verb_with_the_same_outputs(kind, results, campaigns, tmp_path, capsys):
    """Written by the current writer, the ``kind`` key deleted: what today's version wrote. Every verb that takes
    the kind runs on it and writes what it writes for the file with its kind."""
    path, doc = results[kind]
    new_dir, old_dir = tmp_path / "new", tmp_path / "old"
    new_dir.mkdir()
    new = new_dir / "result.json"
    new.write_text(path.read_text())
    old = _legacy(path, doc, old_dir)
    assert "kind" not in json.loads(old.read_text()) and read_result(old)[0] == kind
    for d, result in ((new_dir, new), (old_dir, old)):
        for verb, rest in _inputs(kind, campaigns, d).items():
            code, _, err = olti_in(verb, result, *rest, "--out", _output(verb, d), capsys=capsys)
            assert code == 0, (kind, verb, err)
    for verb in _inputs(kind, campaigns, new_dir):
        a, b = _comparable(_output(verb, new_dir), new_dir), _comparable(_output(verb, old_dir), old_dir)
        if isinstance(a, dict):
            assert not json_differences(a, b), (kind, verb, json_differences(a, b)[:3])
        else:
            assert a == b, (kind, verb)


# -- one route for identify ---------------------------------------------------------------------------------------
def _todays_route(kind, campaigns, out: Path) -> dict:
    """The result document as today's verbs made it, by the library calls they made (before calibration_problem)."""
    from olti_drake.io.budget import budget_or_default

    if kind == "scara":
        from olti_drake.estimation.identification import IdentificationOptions, identify
        from olti_drake.io.csvio import load_campaign
        from olti_drake.io.result import result_dict

        return result_dict(identify(load_campaign(PAPER), IdentificationOptions(model="errormap")))
    if kind == "serial":
        from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial
        from olti_drake.io.serial_io import load_robot, read_serial_campaign, serial_result_dict

        chain = load_robot("ur5", "tool0")
        camp = read_serial_campaign(campaigns["serial"], chain.n_joints, robot="ur5")
        ident = identify_serial(chain, camp, SerialIdentificationOptions(model="errormap", tool_offset_mm=TOOL,
                                                                         grid_step_deg=30.0))
        return serial_result_dict(kind="errormap", robot_file="ur5", measurement=ident.measurement, fit=ident.fit,
                                  gauge=ident.gauge, campaign_digest=camp.digest(),
                                  notes=list(chain.notes) + ident.notes)
    from olti_drake.estimation.multilateration import MultilaterationOptions, load_machine_campaign, multilaterate

    budget = budget_or_default(None, "machine")
    data = load_machine_campaign(campaigns[kind])
    if kind == "multilateration":
        return multilaterate(data, MultilaterationOptions(gauge="best-fit"), budget).to_dict()
    from olti_drake.estimation.volumetric import VolumetricOptions, identify_volumetric, volumetric_campaign

    return identify_volumetric(volumetric_campaign(data), VolumetricOptions(
        tool_offsets_mm=[list(t) for t in TOOLS], pitch_mm=10.0, budget=budget), budget).to_dict()


@pytest.mark.parametrize("kind", ["scara", "serial", "multilateration", "volumetric"])
def test_identify_through_calibration_problem_gives_todays_result(kind, results, campaigns, tmp_path):
    """campaign CSV -> calibration_problem -> fit -> document: the numbers of today's route within 1e-9 (relative)
    and every other field equal; only the ``kind`` key is new."""
    mine = dict(results[kind][1])
    assert mine.pop("kind") == kind
    today = json.loads(json.dumps(_todays_route(kind, campaigns, tmp_path)))
    today.pop("kind", None)
    diffs = json_differences(mine, today, rel_tol=1e-9, abs_tol=1e-12)
    assert not diffs, diffs[:5]


def test_multilaterate_budget_residuals_takes_the_residual_variance(campaigns, tmp_path, capsys):
    from olti_drake.estimation.multilateration import MultilaterationOptions, load_machine_campaign, multilaterate

    code, _, err = olti_in("multilaterate", campaigns["multilateration"], "--budget", "residuals", "--out",
                           tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    mine = json.loads((tmp_path / "r.json").read_text())
    today = json.loads(json.dumps(multilaterate(load_machine_campaign(campaigns["multilateration"]),
                                                MultilaterationOptions(gauge="best-fit"), None).to_dict()))
    assert "residual variance" in mine["uncertainty"]["method"]
    assert not json_differences(mine, today, rel_tol=1e-9, abs_tol=1e-12)


# -- the option table ---------------------------------------------------------------------------------------------
def _subparser(verb):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return sub.choices[verb]


def test_the_option_table_names_real_options_and_their_defaults_as_not_given():
    from olti_drake.cli.kinds import HANDLERS, OPTIONS

    for o in OPTIONS:
        action = next((a for a in _subparser(o.verb)._actions if o.flag in a.option_strings), None)
        assert action is not None and action.dest == o.dest, (o.verb, o.flag)
        assert action.default == o.unset, (o.verb, o.flag, action.default, o.unset)
        assert o.kinds and all(k in ("scara", "serial", "multilateration", "volumetric", "machine3d", "machine5") for k in o.kinds)
    assert set(HANDLERS) == {"predict", "uncertainty", "design", "compensate"}


@pytest.mark.parametrize("argv, needles", [
    (["identify", PAPER, "--model", "errormap", "--knot-spacing-mm", "50"], ["--knot-spacing-mm applies to --model "
                                                                            "volumetric"]),
    (["identify", PAPER, "--model", "dh", "--tool-frame", "tool0"], ["--tool-frame needs --robot FILE"]),
    (["identify", PAPER, "--model", "volumetric", "--robot", "ur5"], ["--robot applies to the robot models"]),
    (["identify", PAPER, "--model", "volumetric", "--compliance"], ["--compliance needs --robot FILE",
                                                                    "not --model volumetric"]),
])
def test_an_option_for_another_kind_is_refused_in_one_line(argv, needles, tmp_path, capsys):
    code, _, err = olti_in(*argv, "--out", tmp_path / "r.json", capsys=capsys)
    error_line(code, err, *needles)
    assert not (tmp_path / "r.json").exists()


def test_options_for_another_result_kind_are_refused_by_the_table(results, campaigns, tmp_path, capsys):
    scara, serial, ml, vol = (results[k][0] for k in ("scara", "serial", "multilateration", "volumetric"))
    out = tmp_path / "o"
    for argv, needle in (
            (["uncertainty", serial, campaigns["serial"], "--method", "linear", "--maps", tmp_path / "m.png"],
             "--maps is the SCARA figure"),
            (["uncertainty", ml, campaigns["multilateration"], "--method", "linear", "--maps", tmp_path / "m.png"],
             "--maps (error maps with error bars) applies to SCARA error-map results only"),
            (["compensate", scara, PAPER, "--urdf-out", tmp_path / "x.urdf"], "--urdf-out needs the result of a robot"),
            (["compensate", scara, PAPER, "--grid-pitch-mm", "20"], "--grid-pitch-mm applies to volumetric results"),
            (["design", vol, "--regions", SCARA_REGIONS, "--plan", PAPER], "--plan applies to robots"),
            (["design", scara, "--regions", SCARA_REGIONS, "--workspace-poses", "20"],
             "--workspace-poses applies to robots from a model file")):
        code, _, err = olti_in(*argv, "--out", out, capsys=capsys)
        error_line(code, err, needle)
        assert not out.exists()


# -- the kind is asked in the registries only -----------------------------------------------------------------------
#: The modules that tell kinds apart (and what they tell).
REGISTRIES = {"olti_drake/io/documents.py": "result kinds", "olti_drake/formats.py": "format ids",
              "olti_drake/estimation/problem.py": "calibration kinds",
              "olti_drake/sim/serial_scenario.py": "scenario kinds"}
#: Modules that compare a document's format with their own one format to validate it (no kind is told apart).
FORMAT_CHECKS = {"olti_drake/io/csvio.py": "read_json: the format a caller asks for",
                 "olti_drake/model/volumetric3d.py": "model_from_document: its own document",
                 "olti_drake/hardware/runlog.py": "the run manifest"}
FORMAT_ID = re.compile(r"^olti-[a-z0-9-]+/\d+$")


def _is_format_lookup(node) -> bool:
    """``X["format"]`` or ``X.get("format")``."""
    if isinstance(node, ast.Subscript):
        s = node.slice
        return isinstance(s, ast.Constant) and s.value == "format"
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
            and node.args and isinstance(node.args[0], ast.Constant) and node.args[0].value == "format")


def _docstrings(tree) -> set:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def kind_sniffing_sites(sources=None) -> list:
    """["path:line: what"] of every place outside the registries that tells a kind apart by itself, in
    ``sources`` ({path relative to the checkout: text}; default every module of the package)."""
    if sources is None:
        sources = {p.relative_to(ROOT).as_posix(): p.read_text(encoding="utf-8") for p in sorted(PKG.rglob("*.py"))}
    sites = []
    for rel, text in sources.items():
        tree = ast.parse(text, rel)
        docs = _docstrings(tree)
        for node in ast.walk(tree):
            where = f"{rel}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                name, args = node.func.id, node.args
                if name == "isinstance" and args and isinstance(args[0], ast.Call) and isinstance(
                        args[0].func, ast.Attribute) and args[0].func.attr == "get" and args[0].args and isinstance(
                        args[0].args[0], ast.Constant) and args[0].args[0].value == "robot" and rel not in REGISTRIES:
                    sites.append(f"{where}: isinstance(.get('robot'), ...)")
                if name == "hasattr" and len(args) == 2 and isinstance(args[1], ast.Constant) and args[1].value in (
                        "n_joints", "robot", "machine"):
                    sites.append(f"{where}: hasattr(..., {args[1].value!r})")
                if name in ("is_serial_result", "is_serial_scenario", "is_machine3d_scenario", "_result_format"):
                    sites.append(f"{where}: {name}()")
            if isinstance(node, ast.FunctionDef) and node.name == "scenario_kind" and rel != \
                    "olti_drake/sim/serial_scenario.py":
                sites.append(f"{where}: a second scenario_kind")
            if isinstance(node, ast.Compare) and rel not in REGISTRIES and rel not in FORMAT_CHECKS and any(
                    _is_format_lookup(n) for n in [node.left] + node.comparators):
                sites.append(f"{where}: a comparison of the 'format' key")
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and FORMAT_ID.match(node.value) and \
                    id(node) not in docs and rel != "olti_drake/formats.py":
                sites.append(f"{where}: format id {node.value!r} spelled out")
    return sites


def test_kinds_are_told_apart_in_the_registries_only():
    assert kind_sniffing_sites() == []
    for module in list(REGISTRIES) + list(FORMAT_CHECKS):
        assert (ROOT / module).is_file(), module


def test_the_sniffing_detector_sees_what_it_forbids():
    """The detector is not blind: the sites of before issue 22, in a module outside the registries, are found."""
    text = ('def f(raw, setup, path):\n    a = isinstance(raw.get("robot"), dict)\n'
            '    b = raw["format"] == "olti-result/1"\n    c = is_serial_result(path)\n'
            '    return a, b, c, hasattr(setup, "n_joints")\n')
    found = kind_sniffing_sites({"olti_drake/cli/planted.py": text})
    assert len(found) == 5, found  # (the comparison, and the format id spelled out in it)
    assert kind_sniffing_sites({"olti_drake/io/documents.py": 'x = isinstance(raw.get("robot"), dict)\n'}) == []
