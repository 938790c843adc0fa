"""Reflector placement design by the linear method (000 §3.2.2 Remark 2, §5): olti_drake.estimation.design, `olti design`.

Truth: the default scenario's robot (paper-000 experiment) sampled on the
plan's grid -- the error-map model an identification of the paper plan
estimates. Budget: 000 Table 2. Costs are predicted-position standard
uncertainties sqrt(u_x² + u_y²) (k = 1) in mm, printed in µm. Coarse
candidate and workspace grids keep the file fast.
"""

import json
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation import design as D
from olti_drake.model.budget import paper000_budget
from olti_drake.model.errormap import sample_map
from olti_drake.estimation.identification import UnidentifiableError
from olti_drake.model.scara import ScaraModel, forward_kinematics
from olti_drake.io.result import _values
from olti_drake.sim.scenario import Scenario
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REGIONS = os.path.join(ROOT, "data", "regions_paper000.yaml")
WORKSPACE_STEP_MM = 75.0


@pytest.fixture(scope="module")
def paper():
    """(truth model, plan, budget, workspace commands, paper reflector layout (3, 2) mm)."""
    sc = Scenario()
    plan = sc.load_plan()
    m = plan.measured()
    r = sc.robot
    model = ScaraModel(r.L1_mm, r.L2_mm, None, sample_map(r.J1, np.unique(m.theta1_deg), "J1"),
                       sample_map(r.J2, np.unique(m.theta2_deg), "J2"))
    ws = D.workspace_commands(model, WORKSPACE_STEP_MM)
    return model, plan, paper000_budget(), ws, np.array(sc.reflectors_mm, dtype=float)


@pytest.fixture(scope="module")
def candidates():
    return D.candidate_grid(D.load_regions(REGIONS), 100.0)


def um(v):
    return f"{1e3 * v:.2f} um"


# -- the cost -------------------------------------------------------------------------------------
def test_designed_layout_beats_the_nearly_collinear_paper_layout(paper, candidates):
    model, plan, budget, ws, P = paper
    for criterion, margin, starts in (("max", 0.95, 2), ("mean", 0.97, 1)):
        paper_cost = D.layout_cost(model, plan, P, budget, ws, criterion)
        res = D.design_layout(model, plan, candidates, 3, budget, ws, criterion, seed=0, starts=starts)
        print(f"\n{criterion} u: paper layout {um(paper_cost)}, designed {um(res.cost)} "
              f"(improvement {paper_cost / res.cost:.3f}x, {res.evaluations} evaluations) at "
              f"{res.reflectors_mm.tolist()}")
        assert res.cost <= margin * paper_cost
        assert res.cost == pytest.approx(D.layout_cost(model, plan, res.reflectors_mm, budget, ws, criterion),
                                         rel=1e-12)
        # The design keeps its rules: separated, feasible, from the candidates.
        Q = res.reflectors_mm
        gaps = [np.hypot(*(Q[i] - Q[j])) for i in range(3) for j in range(i)]
        assert min(gaps) >= D.MIN_SEPARATION_MM
        assert all(res.feasible[res.index])
        assert all(any(np.allclose(q, c) for c in candidates) for q in Q)
        # Every history is non-increasing (exchange only accepts improvements).
        for trace in res.history:
            assert all(b <= a for a, b in zip(trace, trace[1:]))


def test_cost_grows_as_the_reflectors_are_squeezed_onto_a_line(paper):
    model, plan, budget, ws, P = paper
    # The paper layout (x = 650, 700, 650) squeezed onto its own line x = 666.7 mm: a small, steady rise.
    costs = []
    for s in (1.0, 0.5, 0.0):
        Q = P.copy()
        Q[:, 0] = P[:, 0].mean() + s * (P[:, 0] - P[:, 0].mean())
        costs.append(D.layout_cost(model, plan, Q, budget, ws))
    print("\npaper layout squeezed onto x = const (s = 1, 0.5, 0): " + ", ".join(map(um, costs)))
    assert costs[0] < costs[1] < costs[2]
    # A line through the workspace (y = 0): the end effector sits on it (000 §3.2.2 Remark 2) -- a large rise.
    costs = []
    for s in (300.0, 150.0, 0.0):
        Q = np.array([[-700.0, s], [700.0, -s], [850.0, s]])
        costs.append(D.layout_cost(model, plan, Q, budget, ws))
    print("layout squeezed onto y = 0 (offsets 300, 150, 0 mm): " + ", ".join(map(um, costs)))
    assert costs[0] < costs[1] < costs[2]
    assert costs[2] > 1.3 * costs[0]


def test_cached_evaluator_equals_a_fresh_identification(paper):
    """The evaluator copies one Identifier for every layout: same cost as building it anew."""
    model, plan, budget, ws, P = paper
    other = np.array([[650.0, 350.0], [500.0, -900.0], [450.0, -450.0]])
    ev = D.LayoutEvaluator(model, plan, 3, ws)
    ev.cost(P, budget)  # builds the template on the paper layout
    reused = ev.position_std(other, budget)
    fresh = D.LayoutEvaluator(model, plan, 3, ws).position_std(other, budget)
    np.testing.assert_allclose(reused, fresh, rtol=1e-12)
    # Through the public Identifier path by hand: synthetic campaign, truth as x.
    from olti_drake.estimation.identification import IdentificationOptions, Identifier
    from olti_drake.estimation.uncertainty import linear_covariance, prediction_std
    from olti_drake.model.budget import ReadingErrors

    data, d0 = D.synthetic_campaign(model, D.measured_commands(plan), other)
    assert np.allclose(data.displacement_mm[data.reflector == 0][0], 0.0)
    ident = Identifier(data, IdentificationOptions(grid1_deg=model.map1.grid_deg, grid2_deg=model.map2.grid_deg))
    x = np.concatenate([model.parameter_vector(), other.ravel(), d0])
    assert np.max(np.abs(ident.residuals(x)[0])) < 1e-9  # readings are the model's own distances
    u = prediction_std(ident, linear_covariance(ident, x, ReadingErrors(budget)), x, ws)
    np.testing.assert_allclose(np.hypot(*u.T), fresh, rtol=1e-10)


def test_fewer_than_three_reflectors_is_unidentifiable(paper):
    model, plan, budget, ws, P = paper
    with pytest.raises(UnidentifiableError, match="at least 3"):
        D.layout_cost(model, plan, P[:2], budget, ws)
    with pytest.raises(InputError, match="criterion"):
        D.layout_cost(model, plan, P, budget, ws, "median")


# -- the design ------------------------------------------------------------------------------------
def test_coordinate_exchange_is_reproducible_for_a_seed(paper):
    model, plan, budget, ws, _ = paper
    C = D.candidate_grid(D.load_regions(REGIONS), 150.0)
    a = D.design_layout(model, plan, C, 3, budget, ws, seed=7, starts=2)
    b = D.design_layout(model, plan, C, 3, budget, ws, seed=7, starts=2)
    assert np.array_equal(a.reflectors_mm, b.reflectors_mm)
    assert a.cost == b.cost and a.history == b.history and a.evaluations == b.evaluations
    c = D.design_layout(model, plan, C, 3, budget, ws, seed=8, starts=2, max_sweeps=1)
    assert c.start_costs != a.start_costs  # other random starts


def test_degenerate_candidates_give_a_clear_error(paper):
    model, plan, budget, ws, _ = paper
    one_point = np.tile([[700.0, -100.0]], (20, 1))
    with pytest.raises(InputError, match="only 1 distinct position"):
        D.design_layout(model, plan, one_point, 3, budget, ws)
    close = np.array([[700.0, -100.0], [700.0, -60.0], [740.0, -100.0], [740.0, -60.0]])
    with pytest.raises(InputError, match="cannot place 3 reflectors at least 100 mm apart"):
        D.design_layout(model, plan, close, 3, budget, ws)
    in_reach = np.array([[300.0, 0.0], [0.0, -300.0], [200.0, -200.0]])
    with pytest.raises(InputError, match="within 50 mm of the arm"):
        D.design_layout(model, plan, in_reach, 3, budget, ws)
    with pytest.raises(InputError, match=">= 3"):
        D.design_layout(model, plan, np.array([[700.0, 0.0], [800.0, 0.0]]), 2, budget, ws)


def test_unidentifiable_layouts_cost_infinity(paper, monkeypatch):
    model, plan, budget, ws, _ = paper
    C = np.array([[700.0, -100.0], [650.0, 300.0], [500.0, -800.0], [800.0, -500.0]])
    real = D.LayoutEvaluator.cost

    def cost(self, reflectors_mm, budget, criterion="max"):
        if any(np.allclose(p, C[0]) for p in reflectors_mm):
            raise UnidentifiableError("not identifiable: stand-in", ["P0_x_mm"])
        return real(self, reflectors_mm, budget, criterion)

    monkeypatch.setattr(D.LayoutEvaluator, "cost", cost)
    res = D.design_layout(model, plan, C, 3, budget, ws, seed=0, starts=2)
    assert np.isfinite(res.cost) and 0 not in res.index
    monkeypatch.setattr(D.LayoutEvaluator, "cost",
                        lambda self, *a, **k: (_ for _ in ()).throw(UnidentifiableError("stand-in")))
    with pytest.raises(InputError, match="no identifiable layout"):
        D.design_layout(model, plan, C, 3, budget, ws, seed=0, starts=1)


# -- regions, candidates, workspace ------------------------------------------------------------------
@pytest.mark.parametrize("text, needle", [
    ("regions:\n  - {x_mm: [650, 900]}\n", "regions[0]: missing key 'y_mm'"),
    ("regions:\n  - {x_mm: [650, 900], y_mm: [0, 1]}\n  - {x_mm: [900, 650], y_mm: [0, 1]}\n",
     "regions[1].x_mm: expected [lo, hi]"),
    ("regions:\n  - {x_mm: [650, 900], y_mm: [0, abc]}\n", "regions[0].y_mm"),
    ("regions:\n  - {x_mm: [650, 900, 950], y_mm: [0, 1]}\n", "regions[0].x_mm"),
    ("regions:\n  - {x_mm: 650, y_mm: [0, 1]}\n", "regions[0].x_mm"),
    ("regions:\n  - {x_mm: [650, .nan], y_mm: [0, 1]}\n", "regions[0].x_mm"),
    ("regions:\n  - {x_mm: [650, 900], y_mm: [0, 1], z_mm: [0, 1]}\n", "regions[0]: unknown key 'z_mm'"),
    ("regions: []\n", "regions: expected a non-empty list"),
    ("areas:\n  - {x_mm: [650, 900], y_mm: [0, 1]}\n", "unknown key 'areas'"),
    ("regions:\n  - [650, 900]\n", "regions[0]: expected a mapping"),
    ("regions:\n  - {x_mm: [650, 900\n", "not valid YAML"),
])
def test_regions_yaml_errors_name_the_field(tmp_path, text, needle):
    path = tmp_path / "regions.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        D.load_regions(path)
    msg = str(e.value)
    assert needle in msg and str(path) in msg and "\n" not in msg, msg


def test_regions_file_missing_names_the_file(tmp_path):
    with pytest.raises(InputError, match="nope.yaml: regions file not found"):
        D.load_regions(tmp_path / "nope.yaml")


def test_candidate_grid_is_centred_and_deduplicated():
    regions = D.parse_regions([{"x_mm": [0, 250], "y_mm": [0, 100]}, {"x_mm": [0, 250], "y_mm": [0, 100]},
                               {"x_mm": [500, 500], "y_mm": [7, 7]}])
    C = D.candidate_grid(regions, 100.0)
    assert C.tolist() == [[25.0, 0.0], [25.0, 100.0], [125.0, 0.0], [125.0, 100.0], [225.0, 0.0],
                          [225.0, 100.0], [500.0, 7.0]]
    with pytest.raises(InputError, match="step_mm"):
        D.candidate_grid(regions, 0.0)
    # A top-level list is accepted too, and the name is kept.
    assert D.parse_regions([{"x_mm": [1, 2], "y_mm": [3, 4], "name": "a"}])[0] == D.Region((1.0, 2.0), (3.0, 4.0), "a")


def test_paper_regions_are_outside_the_reach_and_clear_of_the_base(paper):
    model, plan, _, ws, P = paper
    C = D.candidate_grid(D.load_regions(REGIONS), 25.0)
    assert np.hypot(*C.T).min() > 600.0
    ok, rejected = D.feasible_candidates(model, plan, C, ws)
    assert ok.all(), rejected
    # The paper's own layout lies in the regions and passes the rules as well.
    ok, _ = D.feasible_candidates(model, plan, P, ws)
    assert ok.all()
    # A reflector beside the robot on +Y: beams from poses at theta1* ~ -100 deg cross the J1 axis.
    ok, rejected = D.feasible_candidates(model, plan, np.array([[0.0, 700.0]]), ws)
    assert not ok[0] and rejected["base"] == 1


def test_workspace_commands_cover_the_map_range_both_directions(paper):
    model, *_ = paper
    ws = D.workspace_commands(model, 50.0)
    g1, g2 = model.map1.grid_deg, model.map2.grid_deg
    assert ws.theta1_deg.min() >= g1[0] and ws.theta1_deg.max() <= g1[-1]
    assert ws.theta2_deg.min() >= g2[0] and ws.theta2_deg.max() <= g2[-1]
    p, _ = forward_kinematics(ws.theta1_deg, ws.theta2_deg, model.L1_mm, model.L2_mm)
    np.testing.assert_allclose(p / 50.0, np.round(p / 50.0), atol=1e-9)  # the XY grid points
    assert len(ws) % 4 == 0
    dirs = set(zip(ws.dir1[:4], ws.dir2[:4]))
    assert dirs == {(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)}
    # The same from the grids (only their ranges count).
    ws2 = D.workspace_commands((g1, g2), 50.0, model.L1_mm, model.L2_mm)
    np.testing.assert_allclose(ws2.theta1_deg, ws.theta1_deg)
    with pytest.raises(InputError, match="D-H model"):
        D.workspace_commands(ScaraModel(), 50.0)
    with pytest.raises(InputError, match="no point"):
        D.workspace_commands(([1.0, 1.1], [30.0, 30.1]), 50.0)


def test_dh_model_layout_cost(paper):
    _, plan, budget, _, P = paper
    m = plan.measured()
    dh = ScaraModel(324.97, 225.004, -5.55e-3)
    ws = D.workspace_commands((m.theta1_deg, m.theta2_deg), 100.0, dh.L1_mm, dh.L2_mm)
    c = D.layout_cost(dh, plan, P, budget, ws)
    assert 0 < c < 0.01  # 3 parameters: far below the error map's u


# -- the command ------------------------------------------------------------------------------------
def test_cli_design(tmp_path, paper):
    model, _, _, _, P = paper
    result = {"format": "olti-result/1", "model": "errormap"}
    result.update(_values(model, P, np.zeros(3)))
    (tmp_path / "result.json").write_text(json.dumps(result))
    r = olti_sub("design", "result.json", "--regions", REGIONS, "--step-mm", 150, "--workspace-step-mm", 100,
                 "--starts", 1, "--out", "design.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    print(r.stdout)
    for needle in ("current (result)", "designed (3 refl.)", "improvement (max u", "designed positions (mm)",
                   "wrote design.json"):
        assert needle in r.stdout
    d = json.loads((tmp_path / "design.json").read_text())
    assert d["format"] == "olti-design/1" and d["criterion"] == "max" and d["budget"] == "paper 000 Table 2"
    assert len(d["reflectors_mm"]) == 3 and d["evaluations"] > 0
    assert d["designed"]["max_u_mm"] <= d["current"]["max_u_mm"]
    assert d["improvement"] == pytest.approx(d["current"]["max_u_mm"] / d["designed"]["max_u_mm"])
    assert d["designed"]["max_U_k2_mm"] == pytest.approx(2 * d["designed"]["max_u_mm"])
    np.testing.assert_allclose(d["current"]["reflectors_mm"], P)

    # Bad regions: one line naming the field; never overwrite an input.
    (tmp_path / "bad.yaml").write_text("regions:\n  - {x_mm: [900, 650], y_mm: [0, 1]}\n")
    r = olti_sub("design", "result.json", "--regions", "bad.yaml", "--out", "d2.json", cwd=tmp_path)
    error_line(r.returncode, r.stderr)
    assert "regions[0].x_mm" in r.stderr
    r = olti_sub("design", "result.json", "--regions", REGIONS, "--out", "result.json", cwd=tmp_path)
    assert r.returncode == 2 and "overwrite an input" in r.stderr
