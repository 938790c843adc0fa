"""``olti design`` of a five-axis result (issue 25, item 5): stations on the bed or riding on the table and R-test
nests chosen among candidates so that the tool points' u from the location errors is smallest
(:mod:`olti_drake.estimation.five_axis_design`). The result: a geometric identification of a small distance campaign
of the A/C trunnion (truth outside the model family: :func:`olti_drake.model.five_axis_truth.synthetic_truth`)."""

import json

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
from olti_drake.estimation.five_axis_design import (NEST_RANGE_SHARES, NEST_STEPS, FiveAxisDesignProblem,
                                                    design_layout, nest_ranges)
from olti_drake.io.five_axis_io import (load_machine5_result, machine5_result_dict, read_five_axis_campaign,
                                        write_five_axis_campaign)
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_truth import synthetic_truth
from tests.estimation.test_five_axis_identify import TABLE_STATIONS, TRUNNION, distance_campaign, no_dropped_truth
from olti_calls import error_line, olti_in

REGIONS = """regions:
- {x_mm: [-900, 900], y_mm: [-900, 900], z_mm: [900, 1200], frame: base}
- {x_mm: [-600, 600], y_mm: [-600, 600], z_mm: [0, 150], frame: workpiece}
- {x_mm: [-150, 150], y_mm: [-150, 150], z_mm: [200, 300], frame: nest}
"""


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    d = tmp_path_factory.mktemp("design")
    m = FiveAxisMachine.from_file(TRUNNION)
    truth = no_dropped_truth(synthetic_truth(m, seed=3))
    write_five_axis_campaign(d / "campaign.csv", distance_campaign(m, truth, 40, 4, TABLE_STATIONS, "workpiece"))
    ident = FiveAxisIdentification(read_five_axis_campaign(d / "campaign.csv", m), m,
                                   FiveAxisOptions(model="geometric"))
    (d / "result.json").write_text(json.dumps(machine5_result_dict(ident, ident.fit(), TRUNNION)))
    (d / "regions.yaml").write_text(REGIONS)
    return d


@pytest.fixture(scope="module")
def problem(result):
    return FiveAxisDesignProblem(load_machine5_result(result / "result.json"), workspace_poses=150, seed=0)


def design(capsys, result, regions, n, out):
    code, text, err = olti_in("design", result / "result.json", "--regions", regions, "--stations", n,
                           "--step-mm", 75 if "nests" in str(regions) else 400, "--workspace-poses", 150,
                           "--out", out, capsys=capsys)
    assert code == 0, err
    return json.loads(out.read_text()), text


def test_designed_nests_beat_clustered_ones_and_the_design_is_seeded(result, problem, capsys):
    (result / "nests.yaml").write_text(REGIONS.splitlines()[0] + "\n" + REGIONS.splitlines()[3] + "\n")
    doc, text = design(capsys, result, result / "nests.yaml", 3, result / "nests.json")
    assert doc["format"] == "olti-design/1" and doc["kind"] == "machine5" and len(doc["designed"]["elements"]) == 3
    assert all(e["kind"] == "nest" and e["frame"] == "workpiece" for e in doc["designed"]["elements"])
    clustered = np.array([[150.0, 50.0, 250.0], [150.0, 30.0, 250.0], [130.0, 50.0, 250.0]])
    cand = problem.candidates(clustered, ["nest"] * 3)
    assert np.all(cand.readings > 0)  # (every clustered nest's path within the travel: a fair comparison)
    poor = problem.report(cand, range(3), "max")
    assert doc["designed"]["max_u_mm"] < 0.75 * poor.max_u_mm, (doc["designed"]["max_u_mm"], poor.max_u_mm)
    assert set(doc["designed"]["identifiable"]) >= set(poor.identifiable)
    assert all((doc["designed"]["location_u"][n] is None) == (n in doc["designed"]["not_identifiable"])
               for n in doc["designed"]["location_u"])
    assert "designed" in text and "identifiable" in text
    again, _ = design(capsys, result, result / "nests.yaml", 3, result / "nests2.json")
    assert again["designed"]["elements"] == doc["designed"]["elements"]


def test_a_mixed_design_is_no_worse_than_the_results_own_stations(result, capsys):
    doc, _ = design(capsys, result, result / "regions.yaml", 4, result / "mixed.json")
    assert doc["current"] is not None and len(doc["current"]["elements"]) == 4
    assert doc["designed"]["cost_mm"] <= doc["current"]["cost_mm"]
    assert doc["candidates"]["by_frame"]["base"] > 0 and doc["candidates"]["by_frame"]["nest"] > 0
    # (the trunnion's A and C are on the table: a station on the bed sees none of their errors)
    assert all(e["frame"] != "base" for e in doc["designed"]["elements"])


def full_jacobian(problem, positions, frames):
    """The stacked Jacobian of a layout's readings over [location errors, every element's own unknowns] (not the
    Schur complements the design sums), rows scaled by the readings' u."""
    n = len(problem.names)
    blocks = []
    for P, f in zip(np.atleast_2d(positions), frames):
        if f == "nest":
            from olti_drake.model.five_axis_plan import rtest_plan

            for share in NEST_RANGE_SHARES:  # (the widest sweep within the travel, as the design's)
                try:
                    plan = rtest_plan(problem.machine, [P], NEST_STEPS, nest_ranges(problem.machine, share))
                    break
                except InputError:
                    continue
            _, J = problem._points(plan.commands, plan.rotary_directions(problem.machine), "workpiece")
            blocks.append((J, np.tile(-np.eye(3), (len(plan), 1))))
        else:
            p, J = problem._frames[f]
            u = (p - P) / np.linalg.norm(p - P, axis=1)[:, None]
            A = np.einsum("ni,nij->nj", u, J.reshape(len(p), 3, n))
            blocks.append((A, np.hstack([-u, -np.ones((len(p), 1))])))
    own = sum(b[1].shape[1] for b in blocks)
    rows, col = [], n
    for A, B in blocks:
        R = np.zeros((len(A), n + own))
        R[:, :n], R[:, col:col + B.shape[1]] = A, B
        rows.append(R)
        col += B.shape[1]
    J = np.vstack(rows)
    return J / np.maximum(np.linalg.norm(J, axis=0), 1e-300)


def rank(A) -> int:
    s = np.linalg.svd(A, compute_uv=False)
    return int(np.sum(s > 1e-8 * s[0]))


@pytest.mark.parametrize("layout", ["table stations", "nests", "bed stations"])
def test_the_identifiability_statement_matches_a_rank_check(problem, layout):
    """With the location errors the design calls not identifiable held (their columns out), the stacked Jacobian
    of the readings and every element's own unknowns has full column rank; each held one, put back, adds no rank
    (it trades with the others or the measurement's gauge); an error no reading moves has a zero column."""
    positions, frames = {
        "table stations": (TABLE_STATIONS, ["workpiece"] * 4),
        "nests": (np.array([[100.0, 0.0, 220.0], [-80.0, 80.0, 250.0], [0.0, -60.0, 260.0]]), ["nest"] * 3),
        "bed stations": (np.array([[-800, -700, 900], [800, -650, 950], [750, 700, 1100], [-700, 750, 1000.0]]),
                         ["base"] * 4)}[layout]
    cand = problem.candidates(positions, frames)
    report = problem.report(cand, range(len(cand)), "max")
    J = np.nan_to_num(full_jacobian(problem, positions, frames))
    n = len(problem.names)
    ok = np.array([problem.names[i] in report.identifiable for i in range(n)])
    own = np.arange(n, J.shape[1])
    kept = np.concatenate([np.flatnonzero(ok), own])
    assert rank(J[:, kept]) == len(kept), (layout, report.identifiable)
    for i in np.flatnonzero(~ok):
        assert rank(J[:, np.append(kept, i)]) == len(kept), (layout, problem.names[i])
    if layout == "bed stations":  # (the trunnion's A and C are on the table: the bed sees neither)
        assert report.identifiable == [] and not np.isfinite(report.cost_mm)
    else:
        assert len(report.identifiable) >= 6, report.identifiable


def test_bad_regions_and_options_are_refused_in_one_line(result, capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("regions:\n- {x_mm: [0, 100], y_mm: [0, 100], z_mm: [0, 100], frame: table}\n")
    code, _, err = olti_in("design", result / "result.json", "--regions", bad, "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "regions[0].frame = 'table'")
    code, _, err = olti_in("design", result / "result.json", "--regions", result / "regions.yaml", "--plan",
                        "data/plan_paper000.csv", "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "--plan")
    few = tmp_path / "few.yaml"
    few.write_text("regions:\n- {x_mm: [-600, 600], y_mm: [0, 0], z_mm: [50, 50], frame: workpiece}\n")
    code, _, err = olti_in("design", result / "result.json", "--regions", few, "--step-mm", 600,
                        "--stations", 5, "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "5")


def test_too_few_readable_candidates_are_refused(problem):
    cand = problem.candidates(np.array([[0.0, 0.0, 100.0]]), ["workpiece"])
    with pytest.raises(InputError, match="1 of 1 candidates|0 of 1 candidates"):
        design_layout(problem, cand, 4)
