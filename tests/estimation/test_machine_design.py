"""Station layout design in 3D for the machine tool (issue 15 item 2): olti design on a 3D multilateration
result -- the per-station information equals the full problem's covariance, the designed layout beats a
clustered one, seeded, degenerate layouts refused by name in one line."""

import json

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.machine_design import (MachineStationInformation, check_design_space,
                                                  design_machine_stations)
from olti_drake.estimation.multilateration import Multilateration, MultilaterationOptions, machine_campaign
from olti_drake.io.budget import default_budget
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.budget import ReadingErrors
from olti_calls import error_line, olti_in

STATIONS = np.array([[-300, -200, 0], [700, -250, 50], [600, 600, 300], [-200, 500, 400], [200, 150, 900.]])
DEAD_PATHS = np.array([0.3, 1.2, -0.4, 2.0, 0.7])
REGIONS = ("regions:\n  - {x_mm: [-400, -200], y_mm: [-300, 600], z_mm: [0, 400]}\n"
           "  - {x_mm: [600, 800], y_mm: [-300, 600], z_mm: [0, 400]}\n"
           "  - {x_mm: [0, 400], y_mm: [-400, -300], z_mm: [0, 400]}\n")


def campaign_columns(seed=0):
    """A 4 x 4 x 3 grid of commands in a 400 x 300 x 250 mm travel, targets off them by 10 µm, read from the
    five stations with the 001 Table 4 noise (seeded)."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.linspace(0, 400, 4), np.linspace(0, 300, 4), np.linspace(0, 250, 3),
                             indexing="ij"), -1).reshape(-1, 3)
    T = g + rng.normal(0, 0.01, g.shape)
    i, j = np.repeat(np.arange(len(T)), len(STATIONS)), np.tile(np.arange(len(STATIONS)), len(T))
    D = np.linalg.norm(T[i] - STATIONS[j], axis=1)
    d = D - DEAD_PATHS[j] + ReadingErrors(default_budget("machine")).draw(rng, D, 1)[0]
    return {"station": j, "target": i, "x_cmd_mm": g[i, 0], "y_cmd_mm": g[i, 1], "z_cmd_mm": g[i, 2],
            "displacement_mm": d}


@pytest.fixture(scope="module")
def solved():
    data = machine_campaign(campaign_columns(), "synthetic")
    return {gk: Multilateration(data, MultilaterationOptions(gauge=gk)).solve(default_budget("machine"))
            for gk in ("best-fit", "first-three")}


def _info(res, gauge):
    return MachineStationInformation(res.targets_mm, res.nominal_mm, gauge, ReadingErrors(default_budget("machine")))


@pytest.mark.parametrize("gauge", ["best-fit", "first-three"])
def test_station_information_equals_the_full_problem_covariance(solved, gauge):
    """Sum of the per-station (Schur-projected) information = the multilateration's own linear covariance
    of the targets (all 48 targets, the budget's distance-dependent u) to 1e-6, in both 3D gauges."""
    res = solved[gauge]
    n = 3 * len(res.targets_mm)
    C = res.fit.covariance[:n, :n].reshape(len(res.targets_mm), 3, len(res.targets_mm), 3)
    full = np.sqrt(np.einsum("iaia->i", C))
    info = _info(res, gauge)
    u = info.position_u(sum(info.block(s)[0] for s in res.stations_mm))
    assert np.allclose(u, full, rtol=1e-6, atol=0)
    assert full.max() > 0 and np.ptp(full) > 0.05 * full.max()  # not a constant: the layout matters


def test_designed_layout_beats_a_clustered_one_and_is_seeded(solved, tmp_path):
    res = solved["best-fit"]
    info = _info(res, "best-fit")
    from olti_drake.estimation.serial_design import candidate_points, load_boxes

    (tmp_path / "r.yaml").write_text(REGIONS)
    cand = candidate_points(load_boxes(tmp_path / "r.yaml"), 300.0)
    d = design_machine_stations(info, cand, 5, seed=3, starts=1, max_sweeps=2)
    again = design_machine_stations(info, cand, 5, seed=3, starts=1, max_sweeps=2)
    assert np.array_equal(d.stations_mm, again.stations_mm) and d.cost_mm == again.cost_mm
    # a clustered layout: the five candidates nearest one corner of the first box
    near = cand[np.argsort(np.linalg.norm(cand - [-400, -300, 0], axis=1))[:5]]
    clustered = np.max(info.position_u(sum(info.block(s)[0] for s in near)))
    assert d.cost_mm < 0.5 * clustered
    assert np.isclose(d.cost_mm, np.max(info.position_u(sum(info.block(s)[0] for s in d.stations_mm))))
    assert all(any(np.allclose(s, c) for c in cand) for s in d.stations_mm)


def test_degenerate_design_spaces_are_refused_by_name(solved):
    cand = np.array([[x, y, 0.0] for x in (-300, 0, 700) for y in (-300, 0, 600)])
    with pytest.raises(InputError, match="one plane"):
        check_design_space(cand, 5, 48)
    with pytest.raises(InputError, match="at least 4 stations"):
        check_design_space(cand + np.outer(np.arange(9), [0, 0, 50.0]), 3, 48)
    with pytest.raises(InputError, match="counting condition"):
        check_design_space(np.random.default_rng(0).uniform(0, 500, (20, 3)), 4, 10)
    res = solved["best-fit"]
    with pytest.raises(InputError, match="larger --step-mm"):
        design_machine_stations(_info(res, "best-fit"), np.random.default_rng(1).uniform(-500, 900, (20000, 3)), 5)
    flat = res.targets_mm.copy()
    flat[:, 2] = 0.0
    with pytest.raises(InputError, match="targets lie in one plane"):
        MachineStationInformation(flat, flat, "best-fit", ReadingErrors(default_budget("machine")))


def test_olti_design_on_a_3d_multilateration_result(tmp_path, capsys):
    write_machine_campaign(campaign_columns(), tmp_path / "c.csv")
    code, out, err = olti_in("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    (tmp_path / "r.yaml").write_text(REGIONS)
    code, out, err = olti_in("design", tmp_path / "r.json", "--regions", tmp_path / "r.yaml", "--stations", 5,
                           "--step-mm", 300, "--starts", 1, "--max-sweeps", 1, "--out", tmp_path / "d.json", capsys=capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["format"] == "olti-design/1" and len(doc["stations_mm"]) == 5 and doc["criterion"] == "max"
    assert np.isfinite(doc["current"]["cost_mm"]) and doc["designed"]["cost_mm"] > 0
    assert "current (result)" in out and "designed (5 stations)" in out
    # coplanar candidates: one error line naming the regions file, nothing written
    (tmp_path / "flat.yaml").write_text("regions:\n  - {x_mm: [-400, 800], y_mm: [-400, 600], z_mm: 0}\n")
    code, out, err = olti_in("design", tmp_path / "r.json", "--regions", tmp_path / "flat.yaml", "--stations",
                           5, "--step-mm", 300, "--out", tmp_path / "d2.json", capsys=capsys)
    error_line(code, err, "flat.yaml")
    assert "one plane" in err and not (tmp_path / "d2.json").exists()
    code, out, err = olti_in("design", tmp_path / "r.json", "--regions", tmp_path / "r.yaml", "--stations",
                           3, "--step-mm", 300, "--out", tmp_path / "d3.json", capsys=capsys)
    error_line(code, err, "at least 4 stations")


def test_a_bad_or_2d_machine_result_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "r.yaml").write_text(REGIONS)
    (tmp_path / "bad.json").write_text(json.dumps({"format": "olti-multilateration/1", "gauge": "g"}))
    code, out, err = olti_in("design", tmp_path / "bad.json", "--regions", tmp_path / "r.yaml",
                           "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "bad.json", "'targets_mm'")
    flat = {"format": "olti-multilateration/1", "gauge": "g", "targets_mm": [[0, 0], [1, 0], [0, 1]],
            "stations_mm": [[5, 5]], "dead_paths_mm": [0]}
    (tmp_path / "two.json").write_text(json.dumps(flat))
    code, out, err = olti_in("design", tmp_path / "two.json", "--regions", tmp_path / "r.yaml",
                           "--out", tmp_path / "d.json", capsys=capsys)
    error_line(code, err, "two.json", "2D")
    assert not (tmp_path / "d.json").exists()
