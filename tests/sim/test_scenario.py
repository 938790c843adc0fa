"""Scenarios: the shipped YAML equals the embedded default; malformed ones fail by field."""

import os

import pytest

from olti_drake.errors import InputError
from olti_drake.io.budget import load_budget
from olti_drake.model.budget import paper000_budget
from olti_drake.sim.scenario import Scenario, as_plain, load_scenario

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PAPER = os.path.join(ROOT, "diagrams", "paper000_scara.yaml")


def test_shipped_scenario_equals_embedded_default():
    s = load_scenario(PAPER)
    a, b = as_plain(s), as_plain(Scenario())
    assert {k for k in a if a[k] != b[k]} == {"budget"}  # a file path vs. the built-in table
    assert as_plain(s.load_budget()) == as_plain(paper000_budget())
    plan_a, plan_b = s.load_plan(), Scenario().load_plan()
    assert (plan_a.theta1_deg == plan_b.theta1_deg).all() and (plan_a.measure == plan_b.measure).all()


def test_shipped_budget_file_equals_table2():
    assert as_plain(load_budget(os.path.join(ROOT, "data", "budget_paper000.yaml"))) == as_plain(paper000_budget())


@pytest.mark.parametrize("yaml_text, field", [
    ("robot: {L1_mm: -325}", "robot.L1_mm"),
    ("robot: {nominal_L2_mm: .nan}", "robot.nominal_L2_mm"),
    ("robot: {beam_offset_mm: [1.0]}", "robot.beam_offset_mm"),
    ("robot: {J1: !HarmonicDeviation {harmonics: [{amplitude_mdeg: 1, period_deg: 0}]}}",
     "robot.J1.harmonics[0].period_deg"),
    ("robot: {J2: !MapTable {grid_deg: [0, 0], forward_deg: [0, 0], reverse_deg: [0, 0]}}", "robot.J2"),
    ("reflectors_mm: []", "reflectors_mm"),
    ("reflectors_mm: [[1, 2, 3]]", "reflectors_mm"),
    ("reflector_estimate: !PerturbedEstimate {sigma_mm: -1}", "reflector_estimate.sigma_mm"),
    ("interferometer: {acceptance_mm: 0}", "interferometer.acceptance_mm"),
    ("period_s: 0", "period_s"),
    ("seed: -1", "seed"),
    ("plan: !PlanFile {path: ''}", "plan.path"),
    ("robot: {L3_mm: 1}", "L3_mm"),
    ("seed: abc", "seed"),
    ("reflector_estimate: !Telepathy {}", "Telepathy"),
])
def test_malformed_scenario_names_the_field(tmp_path, yaml_text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml_text + "\n")
    with pytest.raises(InputError) as e:
        load_scenario(path)
    msg = str(e.value)
    assert "\n" not in msg and field in msg and "bad.yaml" in msg


def test_missing_scenario_file():
    with pytest.raises(InputError, match="nope.yaml: scenario file not found"):
        load_scenario("nope.yaml")


@pytest.mark.parametrize("yaml_text, field", [
    ("contributors: [{symbol: u1, value: 1, unit: um, acts_on: the_moon}]", "acts_on"),
    ("contributors: [{symbol: u1, value: 1, unit: rad, acts_on: reading}]", "unit 'rad'"),
    ("contributors: [{symbol: u1, value: -1, unit: um, acts_on: reading}]", "value"),
    ("contributors: [{symbol: u1, value: 1, unit: um, k: 0, acts_on: reading}]", "k must be"),
    ("contributors: [{symbol: u1, value: 1, unit: um, type: C, acts_on: reading}]", "type"),
    ("contributors: [{symbol: u1, valeu: 1}]", "valeu"),
])
def test_malformed_budget_names_the_field(tmp_path, yaml_text, field):
    path = tmp_path / "budget.yaml"
    path.write_text(yaml_text + "\n")
    with pytest.raises(InputError) as e:
        load_budget(path)
    assert field in str(e.value) and "budget.yaml" in str(e.value) and "\n" not in str(e.value)


# -- NEW (issue 12): scenario objects, one path rule, named scenarios and overrides, prepare validates ------
OLD_EMULATED = """\
reflector_estimate: !SearchEstimate {positions_mm: [], angle_noise_mdeg: -1.0}
budget: ../data/budget_paper000.yaml
station: !Emulated {speed: fast}
"""


def _campaign_bytes(scenario, out):
    from olti_drake.sim.campaign import prepare, run_campaign, write_campaign

    paths = write_campaign(run_campaign(prepare(scenario)), str(out))
    return open(paths[0], "rb").read()


def test_plan_and_budget_as_objects_or_files_give_identical_campaigns(tmp_path):
    """A Plan and a Budget object built in Python = the same plan and budget given as files."""
    from olti_drake.model.budget import paper000_budget
    from olti_drake.sim.scenario import PlanFile

    plan = Scenario().load_plan()
    (tmp_path / "plan.csv").write_text(
        "theta1_deg,theta2_deg,measure\n" + "".join(
            f"{float(a)!r},{float(b)!r},{int(m)}\n" for a, b, m in zip(plan.theta1_deg, plan.theta2_deg, plan.measure)))
    files = Scenario(plan=PlanFile("plan.csv"), budget=os.path.join(ROOT, "data", "budget_paper000.yaml"),
                     seed=4).at(tmp_path)
    objects = Scenario(plan=files.load_plan(), budget=paper000_budget(), seed=4)
    assert files.load_plan() is not plan and (files.load_plan().theta1_deg == plan.theta1_deg).all()
    a = _campaign_bytes(files, tmp_path / "files")
    b = _campaign_bytes(objects, tmp_path / "objects")
    assert a == b and len(a) > 10000


def test_relative_paths_resolve_against_the_yaml_folder_or_the_python_base(tmp_path, monkeypatch):
    """One rule: relative to the YAML file's folder; for a Python-built scenario, the current
    directory unless .at(folder) says otherwise."""
    from olti_drake.sim.scenario import PlanFile

    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "b.yaml").write_text(open(os.path.join(ROOT, "data", "budget_paper000.yaml")).read())
    (sub / "s.yaml").write_text("budget: b.yaml\nplan: !PlanFile {path: p.csv}\n")
    (sub / "p.csv").write_text("theta1_deg,theta2_deg,measure\n0,10,1\n0,20,1\n")
    monkeypatch.chdir(tmp_path)           # the YAML's paths do not depend on where Python runs
    s = load_scenario("sub/s.yaml")
    assert s.resolve(s.budget) == str(sub / "b.yaml") and len(s.load_plan()) == 2
    py = Scenario(budget="sub/b.yaml", plan=PlanFile("sub/p.csv"))     # Python: the current directory
    assert as_plain(py.load_budget()) == as_plain(s.load_budget()) and len(py.load_plan()) == 2
    at = Scenario(budget="b.yaml", plan=PlanFile("p.csv")).at(sub)      # Python: an explicit base
    assert at.resolve("b.yaml") == str(sub / "b.yaml") and len(at.load_plan()) == 2
    with pytest.raises(InputError, match="b.yaml"):
        Scenario(budget="b.yaml").load_budget()                        # not in the current directory


@pytest.mark.parametrize("field, value, message", [
    ("period_s", 0.0, "scenario: period_s must be finite and > 0"),
    ("seed", -2, "scenario: seed must be >= 0"),
    ("plan", "plan.csv", "scenario: plan must be one of Plan, BidirectionalGrid, PlanFile, got str"),
    ("budget", 3.0, "scenario: budget must be one of Budget, str, PathLike, got float"),
])
def test_prepare_validates_a_python_built_scenario_naming_the_field(field, value, message):
    from olti_drake.sim.campaign import prepare

    with pytest.raises(InputError) as e:
        prepare(Scenario(**{field: value}))
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_the_emulated_and_hardware_files_are_overrides_of_the_paper_scenario(tmp_path):
    """paper000_emulated/hardware.yaml name paper000_scara.yaml as base: equal to the old near-copies
    (the whole paper scenario written out plus their keys, in the same folder), and the named
    scenarios of diagrams/scenarios.yaml equal them too."""
    text = open(PAPER).read().replace("../data/", os.path.join(ROOT, "data", ""))
    copies = {"emulated": text + "station: !Emulated {speed: fast}\n",
              "hardware": text.replace("reflector_estimate: !SearchEstimate",
                                       "reflector_estimate: !ExactEstimate {}\nunused: !SearchEstimate")
              .replace("unused: !SearchEstimate\n  positions_mm: []", "").replace(
                  "  angle_noise_mdeg: -1.0      # negative: the beam found within 0.1 mm at the reflector\n", "")
              + "station: !Hardware {robot_port: /dev/ttyUSB0, counter_port: /dev/ttyUSB1, baud: 115200}\n"}
    for name, copy in copies.items():
        (tmp_path / f"{name}.yaml").write_text(copy)
        near = load_scenario(tmp_path / f"{name}.yaml")
        near.budget = "../data/budget_paper000.yaml"      # the shipped copy's path, relative to diagrams/
        new = load_scenario(os.path.join(ROOT, "diagrams", f"paper000_{name}.yaml"))
        named = load_scenario(os.path.join(ROOT, "diagrams", "scenarios.yaml"), f"paper000_{name}")
        assert as_plain(new) == as_plain(near) == as_plain(named), name
        assert open(os.path.join(ROOT, "diagrams", f"paper000_{name}.yaml")).read().count("\n") < 25
    bench = load_scenario(os.path.join(ROOT, "diagrams", "scenarios.yaml"), "paper000_bench")
    assert bench.station.counter_driver == "bench" and bench.station.robot_port == "/tmp/olti-robot"
    assert as_plain(bench.reflector_estimate) == as_plain(named.reflector_estimate)   # the hardware base's


def test_a_named_scenario_with_overrides_gives_the_same_campaign_bytes_as_the_near_copy(tmp_path):
    near = tmp_path / "near.yaml"
    near.write_text(open(PAPER).read().replace("seed: 0", "seed: 3").replace(
        "../data/", os.path.join(ROOT, "data", "")))
    named = load_scenario(os.path.join(ROOT, "diagrams", "scenarios.yaml"), "paper000_scara", "{seed: 3}")
    assert named.seed == 3
    assert _campaign_bytes(load_scenario(near), tmp_path / "a") == _campaign_bytes(named, tmp_path / "b")
    assert _campaign_bytes(load_scenario(PAPER), tmp_path / "c") != _campaign_bytes(named, tmp_path / "d")


@pytest.mark.parametrize("text, message", [
    ("a: {seed: 1}\n", "no scenario named 'b' (names: a)"),
    ("b: {base: '#b'}\n", "is its own base (a cycle)"),
    ("b: {base: nowhere.yaml}\n", "nowhere.yaml: scenario file not found"),
    ("b: {seed: abc}\n", "seed"),
])
def test_bad_named_scenarios_are_one_line_errors(tmp_path, text, message):
    path = tmp_path / "named.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        load_scenario(path, "b")
    assert message in str(e.value) and "\n" not in str(e.value)


def test_scenario_text_overrides_and_names_its_error(tmp_path):
    s = load_scenario(PAPER, text="{seed: 7, station: !Emulated {drop: 0.25}}")
    assert s.seed == 7 and s.station.drop == 0.25 and s.robot.L1_mm == Scenario().robot.L1_mm
    with pytest.raises(InputError, match=r"scenario text .*seed"):
        load_scenario(PAPER, text="{seed: -1}")
    with pytest.raises(InputError, match=r"scenario text"):
        load_scenario(PAPER, text="{sed: 1}")


def _imports(module_path):
    """Every ``olti_drake...`` module a file imports, at the top or inside functions (AST)."""
    import ast

    out = set()
    for node in ast.walk(ast.parse(open(module_path, encoding="utf-8").read())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("olti_drake"):
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("olti_drake")}
    return out


def test_no_import_circles_between_the_scenario_the_hardware_and_the_cli():
    """hardware/ never imports cli/ or report/; sim/scenario never imports hardware/ (the emulator's Faults
    live in the scenario); drivers never import the station (open_serial lives in drivers). The station
    factory (hardware.station.AddStation) may import sim.campaign: sim never imports hardware
    (tests/package/test_layers.py checks the whole graph)."""
    pkg = os.path.join(ROOT, "olti_drake")
    for name in sorted(os.listdir(os.path.join(pkg, "hardware"))):
        if name.endswith(".py"):
            bad = {m for m in _imports(os.path.join(pkg, "hardware", name))
                   if m.startswith(("olti_drake.cli", "olti_drake.report"))}
            assert not bad, (name, bad)
    assert not {m for m in _imports(os.path.join(pkg, "sim", "scenario.py")) if m.startswith("olti_drake.hardware")}
    assert not {m for m in _imports(os.path.join(pkg, "hardware", "drivers.py"))
                if m.startswith("olti_drake.hardware.station")}
    from olti_drake.hardware.emulator import Faults
    from olti_drake.hardware import station
    from olti_drake.sim import scenario
    from olti_drake.hardware import drivers
    assert Faults is scenario.Faults and not hasattr(station, "open_serial") and callable(drivers.open_serial)


# -- NEW (issue 12): one seeding mechanism, named streams ----------------------------------------------------
def test_named_seed_streams_are_independent_and_reproducible(tmp_path):
    """Every random source draws from its own named stream of the scenario seed: a consumer that draws
    more numbers from its stream (a perturbed estimate of sigma 0 draws, the exact one does not) leaves
    the laser's noise where it was; the same seed gives identical bytes, another seed other bytes."""
    from olti_drake.sim.scenario import (SEED_STREAMS, ExactEstimate, PerturbedEstimate, stream_key, stream_rng,
                                         stream_seed)

    assert len(set(SEED_STREAMS.values())) == len(SEED_STREAMS)
    assert stream_key("laser") == SEED_STREAMS["laser"] and stream_key(11) == 11
    with pytest.raises(KeyError, match="not one of"):
        stream_key("lazer")
    a = stream_rng(3, "emulator_noise").standard_normal(4)
    assert (a == stream_rng(3, "emulator_noise").standard_normal(4)).all()
    assert not (a == stream_rng(3, "emulator_faults", 0).standard_normal(4)).any()
    assert stream_seed(3, "laser") != stream_seed(4, "laser") != stream_seed(3, "reflector_estimate")
    base = dict(seed=5, reflector_estimate=ExactEstimate())
    exact = _campaign_bytes(Scenario(**base), tmp_path / "exact")
    drawing = _campaign_bytes(Scenario(**{**base, "reflector_estimate": PerturbedEstimate(0.0, 0.0)}),
                              tmp_path / "drawing")
    assert exact == drawing                                    # the estimate stream's draws shift nothing else
    assert exact == _campaign_bytes(Scenario(**base), tmp_path / "again")
    assert exact != _campaign_bytes(Scenario(**{**base, "seed": 6}), tmp_path / "other")
    # The emulator's streams are the registry's (its noise and faults by name).
    from olti_drake.hardware import emulator
    assert (emulator.STREAM_NOISE, emulator.STREAM_FAULTS) == (SEED_STREAMS["emulator_noise"],
                                                               SEED_STREAMS["emulator_faults"])
