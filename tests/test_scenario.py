"""Scenarios: the shipped YAML equals the embedded default; malformed ones fail by field."""

import os

import pytest

from olti_drake.io.budget import load_budget, paper000_budget
from olti_drake.io.csvio import InputError
from olti_drake.sim.scenario import Scenario, as_plain, load_scenario

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
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
