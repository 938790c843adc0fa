"""``olti design`` on a 3D machine-tool result finishes with its defaults (issue 24, class 5: it ran > 22 min on the
machine_3d walk-through's multilateration, without output). The layouts' target u are evaluated from the structure
of the multilateration (``machine_design.LayoutCosts``: per target 3 x 3 blocks and a small dense system per
layout, a whole slot's candidates at once) instead of dense (3 N_i)² matrices; without ``--step-mm`` the candidate
step comes from the regions' size; a setting whose estimated run time or memory is absurd is refused in one line
before any work. Speed is measured in benchmarks/bench_machine_design.py, not here."""

import json

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.machine_design import (DEFAULT_CANDIDATES, LayoutCosts, check_design_time,
                                                  default_step_mm, design_machine_stations, design_targets,
                                                  evaluate_machine_layout)
from olti_drake.estimation.serial_design import candidate_points, load_boxes
from olti_drake.io.csvio import write_machine_campaign
from olti_calls import error_line, olti_in
from tests.estimation.test_machine_design import REGIONS, _info, campaign_columns, solved  # noqa: F401 (a fixture)


@pytest.mark.parametrize("gauge", ["best-fit", "first-three"])
def test_the_structured_evaluation_equals_the_dense_sandwich(solved, gauge):
    """Every layout of a batch (four fixed stations + each candidate) has the u of the dense per-station sandwich
    (MachineStationInformation.position_u, itself equal to the multilateration's covariance) to 1e-9."""
    res = solved[gauge]
    info = _info(res, gauge)
    rng = np.random.default_rng(2)
    cand = np.vstack([res.stations_mm, rng.uniform([-400, -400, 0], [800, 700, 900], (6, 3))])
    costs = LayoutCosts(info.targets_mm, info.nominal_mm, gauge, info.errors, cand)
    batch = costs.u([0, 1, 2, 3], np.arange(4, len(cand)))
    for k, c in enumerate(range(4, len(cand))):
        dense = info.position_u(sum(info.block(s)[0] for s in cand[[0, 1, 2, 3, c]]))
        seen = dense > 0
        assert np.allclose(batch[k][seen], dense[seen], rtol=1e-9, atol=0), k
    assert np.allclose(evaluate_machine_layout(info, res.stations_mm)["max_u_mm"],
                       np.max(info.position_u(sum(info.block(s)[0] for s in res.stations_mm))), rtol=1e-9)
    # coplanar stations cannot solve: inf, as the dense path says
    flat = res.stations_mm.copy()
    flat[:, 2] = 0.0
    assert np.all(np.isinf(costs.layout_u(flat)))


def test_the_default_design_of_a_3d_result_finishes(tmp_path, capsys):
    """olti design with its defaults (no --step-mm, 3 starts, 5 sweeps) on a 3D multilateration result returns,
    with a candidate step from the regions' size."""
    write_machine_campaign(campaign_columns(), tmp_path / "c.csv")
    code, out, err = olti_in("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    (tmp_path / "r.yaml").write_text(REGIONS)
    code, out, err = olti_in("design", tmp_path / "r.json", "--regions", tmp_path / "r.yaml",
                           "--out", tmp_path / "d.json", capsys=capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "d.json").read_text())
    assert len(doc["stations_mm"]) == 5 and np.isfinite(doc["designed"]["cost_mm"])
    assert 4 <= doc["candidates"]["count"] <= DEFAULT_CANDIDATES
    targets = design_targets(tmp_path / "r.json").targets_mm
    assert doc["candidates"]["step_mm"] == default_step_mm(load_boxes(tmp_path / "r.yaml"), targets) > 50
    assert "--step-mm not given" in out
    assert err == ""  # no progress line when stderr is not a terminal


def test_the_designed_layout_is_the_dense_evaluations_optimum(solved, tmp_path):
    """The batched exchange is the serial design's rule: seeded, and its cost is the dense u of its layout."""
    res = solved["best-fit"]
    info = _info(res, "best-fit")
    (tmp_path / "r.yaml").write_text(REGIONS)
    cand = candidate_points(load_boxes(tmp_path / "r.yaml"), 300.0)
    seen = []
    d = design_machine_stations(info, cand, 5, seed=3, starts=2, max_sweeps=3,
                                progress=lambda start, sweep, cost: seen.append((start, sweep, cost)))
    again = design_machine_stations(info, cand, 5, seed=3, starts=2, max_sweeps=3)
    assert np.array_equal(d.stations_mm, again.stations_mm) and d.cost_mm == again.cost_mm
    assert np.isclose(d.cost_mm, np.max(info.position_u(sum(info.block(s)[0] for s in d.stations_mm))), rtol=1e-9)
    assert seen and {s for s, _, _ in seen} == {0, 1}
    assert all(b[2] <= a[2] for a, b in zip(seen, seen[1:]) if a[0] == b[0])  # each start only improves


def test_an_absurd_run_time_or_memory_is_refused_before_any_work(solved, tmp_path, capsys):
    with pytest.raises(InputError, match=r"would run up to ~[\d.]+ (min|h) .*larger --step-mm"):
        check_design_time(360, 200_000, 5, 3, 5)
    check_design_time(360, DEFAULT_CANDIDATES, 5, 3, 5)  # the defaults pass
    write_machine_campaign(campaign_columns(), tmp_path / "c.csv")
    code, out, err = olti_in("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    (tmp_path / "r.yaml").write_text(REGIONS)
    code, out, err = olti_in("design", tmp_path / "r.json", "--regions", tmp_path / "r.yaml", "--step-mm", 8,
                           "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "--step-mm")
    assert not (tmp_path / "d.json").exists()
