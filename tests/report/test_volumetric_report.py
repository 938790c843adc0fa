"""olti report on a volumetric result (olti-volumetric/1, issue 15 item 5) and on a 3D multilateration result:
every error motion, the squareness, the volumetric error before/after compensation equal to a direct
computation, the held motions, residuals per station with --campaign, one-line errors."""

import html
import json
import re

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.io.volumetric_io import load_volumetric_result
from olti_drake.model.volumetric3d import ALL_MOTIONS, AXES, SQUARENESS, MachineConfig, synthetic_truth
from olti_drake.report.volumetric_report import grid_pitch_mm, volumetric_figures

from olti_calls import error_line, olti_in
from tests.cli.test_volumetric_cli import DEAD_PATHS, STATIONS, write_campaign
from tests.cli.test_volumetric_cli import NOMINAL_TOOLS as TOOLS


def simulate(path, k, n=150, seed=1):
    """A seeded 3D distance campaign of a synthetic truth: travel corners + n random commands, k tools, the
    five stations, the 001 Table 4 noise."""
    cfg = MachineConfig(tool_offsets_mm=TOOLS[:k], knot_spacing_mm=100.0)
    truth = synthetic_truth(cfg, 3)
    write_campaign(cfg, truth, k, path, n, seed)


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """{k: directory with campaign.csv, result.json} for 3- and 1-tool campaigns."""
    out = {}
    for k in (3, 1):
        d = tmp_path_factory.mktemp(f"vol{k}")
        simulate(d / "campaign.csv", k)
        tools = ";".join(",".join(f"{v:g}" for v in t) for t in TOOLS[:k])
        assert main(["identify", str(d / "campaign.csv"), "--model", "volumetric", "--tool-offsets-mm", tools,
                     "--knot-spacing-mm", "100", "--out", str(d / "result.json")]) == 0
        out[k] = d
    return out


def _text(path):
    """The page's text with tags removed and entities decoded."""
    return html.unescape(re.sub(r"<[^>]+>", " ", path.read_text()))


def test_report_shows_every_motion_squareness_and_the_volumetric_figures(identified, tmp_path, capsys):
    d = identified[3]
    code, out, err = olti_in("report", d / "result.json", "--campaign", d / "campaign.csv", "--out",
                           tmp_path / "rep", capsys=capsys)
    assert code == 0, err
    page = _text(tmp_path / "rep" / "report.html")
    doc = json.loads((d / "result.json").read_text())
    for name in ALL_MOTIONS + SQUARENESS:
        assert name in page, name
    for axis in AXES:
        assert (tmp_path / "rep" / f"fig_motions_{axis}.png").stat().st_size > 10_000
    for name in ("fig_volumetric_error.png", "fig_station_layout.png", "fig_residuals.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 10_000
    for s in SQUARENESS:  # value and U (k = 2) as in the result
        assert f"{doc['squareness_urad'][s]:+.3f}" in page
        assert f"{2 * doc['uncertainty']['squareness_urad'][s]:.3f}" in page
    assert doc["gauge"] in page and "none held at 0" in page
    # The volumetric error by a direct computation: the truth-free model on the grid, its Jacobian and covariance.
    res = load_volumetric_result(d / "result.json")
    cfg = res.model.config
    figs = volumetric_figures(res, 2.0)
    for tool in range(3):
        pitch = grid_pitch_mm(cfg)
        ticks = [np.append(np.arange(lo, hi - 1e-9 * pitch, pitch), hi) for lo, hi in cfg.travel_mm.values()]
        c = np.stack(np.meshgrid(*ticks, indexing="ij"), -1).reshape(-1, 3)
        e = res.model.positions(c, np.full(len(c), tool), res.params) - c - cfg.tools[tool]
        _, J = res.model.jacobian(c, np.full(len(c), tool), res.params)
        cov = np.einsum("mip,pq,mjq->mij", J, res.covariance, J)
        U = 2 * np.sqrt(np.trace(cov, axis1=1, axis2=2))
        f = figs[tool]
        assert np.isclose(f["max_error_mm"], np.linalg.norm(e, axis=1).max(), rtol=1e-12)
        assert np.isclose(f["mean_error_mm"], np.linalg.norm(e, axis=1).mean(), rtol=1e-12)
        assert np.allclose(f["range_mm"], e.max(axis=0) - e.min(axis=0), rtol=1e-12)
        assert np.isclose(f["max_U_mm"], U.max(), rtol=1e-9) and np.isclose(f["mean_U_mm"], U.mean(), rtol=1e-9)
        row = (f"{tool} {1e3 * np.linalg.norm(e, axis=1).max():.2f} {1e3 * np.linalg.norm(e, axis=1).mean():.2f} "
               + " ".join(f"{1e3 * v:.2f}" for v in e.max(axis=0) - e.min(axis=0))
               + f" {1e3 * U.max():.3f} {1e3 * U.mean():.3f}")
        assert row in " ".join(page.split()), row
        assert U.max() < 0.25 * np.linalg.norm(e, axis=1).max()  # compensation leaves far less than it removes
    # Residuals per station at the result's parameters: their RMS is the identification's
    rms = float(doc["residual_rms_mm"])
    assert f"all {doc['n_readings']} {1e3 * rms:.3f}" in " ".join(page.split())


def test_one_tool_report_names_the_held_motions_and_why(identified, tmp_path, capsys):
    d = identified[1]
    code, out, err = olti_in("report", d / "result.json", "--out", tmp_path / "rep", capsys=capsys)
    assert code == 0, err
    page = " ".join(_text(tmp_path / "rep" / "report.html").split())
    held = json.loads((d / "result.json").read_text())["held_motions"]
    assert set(held) == {"E_CY", "E_CZ", "E_AZ", "E_BZ"}
    for name, why in held.items():
        assert f"{name} {' '.join(why.split())}" in page
    assert page.count("held at 0") >= 4
    assert "Give the campaign (--campaign)" in page


def test_bad_input_is_one_error_line(identified, tmp_path, capsys):
    d3, d1 = identified[3], identified[1]
    code, out, err = olti_in("report", d3 / "result.json", "--campaign", d1 / "campaign.csv", "--out",
                           tmp_path / "a", capsys=capsys)
    error_line(code, err, "campaign.csv")
    (tmp_path / "u.json").write_text("{}")
    code, out, err = olti_in("report", d3 / "result.json", tmp_path / "u.json", "--out", tmp_path / "b", capsys=capsys)
    error_line(code, err, "u.json", "volumetric")
    doc = json.loads((d3 / "result.json").read_text())
    del doc["uncertainty"]["covariance"]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    code, out, err = olti_in("report", tmp_path / "bad.json", "--out", tmp_path / "c", capsys=capsys)
    error_line(code, err, "bad.json", "covariance")
    assert not any((tmp_path / x).exists() for x in "abc")


def test_a_3d_multilateration_result_is_reported_with_z(tmp_path, capsys):
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.linspace(0, 400, 4), np.linspace(0, 300, 4), np.linspace(0, 250, 3),
                             indexing="ij"), -1).reshape(-1, 3)
    T = g + rng.normal(0, 0.01, g.shape)
    i, j = np.repeat(np.arange(len(T)), len(STATIONS)), np.tile(np.arange(len(STATIONS)), len(T))
    D = np.linalg.norm(T[i] - STATIONS[j], axis=1)
    write_machine_campaign({"station": j, "target": i, "x_cmd_mm": g[i, 0], "y_cmd_mm": g[i, 1],
                            "z_cmd_mm": g[i, 2], "displacement_mm": D - DEAD_PATHS[j]}, tmp_path / "c.csv")
    code, out, err = olti_in("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    code, out, err = olti_in("report", tmp_path / "r.json", "--campaign", tmp_path / "c.csv", "--out",
                           tmp_path / "rep", capsys=capsys)
    assert code == 0, err
    page = " ".join(_text(tmp_path / "rep" / "report.html").split())
    res = json.loads((tmp_path / "r.json").read_text())
    assert "in 3D" in page and "z*, mm" in page and "u_z, µm" in page and "Δz, µm" in page
    p = np.asarray(res["targets_mm"])
    assert " ".join(f"{v:.4f}" for v in p[7]) in page  # every target with its three coordinates
    S = np.asarray(res["stations_mm"])
    assert "4 " + " ".join(f"{v:.4f}" for v in S[4]) in page
    for name in ("fig_targets.png", "fig_target_uncertainty.png", "fig_residuals.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 10_000


def test_olti_design_on_a_volumetric_result(identified, tmp_path, capsys):
    """olti design RESULT.json with a volumetric result: the targets are the identified tool points on a 3^3 grid
    of the travel x every tool (estimation.machine_design), the result's stations the current layout."""
    d = identified[3]
    (tmp_path / "r.yaml").write_text("regions:\n  - {x_mm: [-400, -200], y_mm: [-300, 600], z_mm: [0, 400]}\n"
                                     "  - {x_mm: [600, 800], y_mm: [-300, 600], z_mm: [0, 900]}\n")
    code, out, err = olti_in("design", d / "result.json", "--regions", tmp_path / "r.yaml", "--step-mm", 300,
                           "--starts", 1, "--max-sweeps", 1, "--out", tmp_path / "d.json", capsys=capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "d.json").read_text())
    assert "81 targets" in doc["targets"] and len(doc["stations_mm"]) == 5 and len(doc["u_targets_mm"]) == 81
    assert np.isfinite(doc["current"]["cost_mm"]) and doc["current"]["stations_mm"] == \
        json.loads((d / "result.json").read_text())["stations_mm"]
    assert doc["designed"]["cost_mm"] == pytest.approx(max(doc["u_targets_mm"]))
