"""The smoothness prior on the 21 ISO 230-1 error motions of a 3-axis machine (issue 23: "built once, in the shared
engine, so that every model gets it"): ``--smoothing auto`` puts the motions on knots twice as fine as the
commanded positions (``estimation.volumetric.smooth_knot_spacing``) under a prior on each motion's ∫ f''² (angular
motions at a lever, ``model.volumetric3d.motion_roughness``) whose weight the readings choose by restricted maximum
likelihood -- the engine's, as for the robots' maps.

Campaigns: the numpy twin of the shipped diagram (pan/tilt heads aimed open loop, 001 Table 4 noise), truths sums
of sines in no spline family (seeded); errors measured at 500 unseen random commands within the travel.
"""

import numpy as np
import pytest

from olti_drake.estimation.multilateration import load_machine_campaign
from olti_drake.estimation.volumetric import (VolumetricOptions, identify_volumetric, smooth_knot_spacing,
                                              volumetric_campaign)
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.propagation import predicted_std
from olti_drake.model.volumetric3d import (MachineConfig, VolumetricModel, motion_roughness, tool_positions)

TOOLS = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0), (0.0, 80.0, 140.0))


def test_the_roughness_rows_integrate_the_squared_second_derivative_exactly():
    cfg = MachineConfig(travel_mm={"X": (0, 400), "Y": (0, 300), "Z": (0, 250)}, knot_spacing_mm=50.0)
    model = VolumetricModel(cfg)
    R = motion_roughness(model, lever_mm=250.0)
    splines = model.motions(model.zeros())
    q = np.linspace(0.0, 400.0, 300)
    for name, a, scale in (("E_XX", 1e-5, 1.0), ("E_BX", 3e-4, 250.0 * 1e-6)):  # mm; µrad at the lever
        B = splines.basis("X", q)[:, model.free[name]]
        theta = model.zeros()
        theta[model.slices[name]] = np.linalg.lstsq(B, a * q ** 2, rcond=None)[0]  # f = a q², exact on the basis
        assert float(np.sum((R @ theta) ** 2)) == pytest.approx((2 * a * scale) ** 2 * 400.0, rel=1e-9)
    line = model.zeros()  # a straight positioning error (a scale error): no roughness
    line[model.slices["E_XX"]] = np.linalg.lstsq(splines.basis("X", q)[:, model.free["E_XX"]], 2e-5 * q,
                                                 rcond=None)[0]
    assert np.max(np.abs(R @ line)) < 1e-12
    squareness = model.zeros()
    squareness[model.slices["E_C0Y"]] = 30.0
    assert np.allclose(R @ squareness, 0.0)  # constants: no roughness


def _campaign(tmp_path, grid, truth_knots_mm, seed):
    from olti_drake.model.machine import Machine3DScenario, machine_run_3d, simulate_machine_campaign_3d

    cfg = MachineConfig(tool_offsets_mm=TOOLS, knot_spacing_mm=truth_knots_mm)
    scenario = Machine3DScenario(config=cfg, grid=grid, tools=(0, 1, 2), seed=seed, truth_seed=seed)
    cols, _ = simulate_machine_campaign_3d(scenario)
    path = tmp_path / f"campaign_{seed}.csv"
    write_machine_campaign(cols, path)
    run = machine_run_3d(scenario)
    return volumetric_campaign(load_machine_campaign(path)), run


def _unseen(result, run, n=500, seed=9):
    """(errors, u) of the tool points at n random commands within the travel (tool 0), mm."""
    cfg = result.model.config
    lo = np.array([cfg.travel_mm[a][0] for a in "XYZ"])
    hi = np.array([cfg.travel_mm[a][1] for a in "XYZ"])
    cmd = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    tool = np.zeros(n, int)
    p, J = result.model.jacobian(cmd, tool, result.params)
    return p - tool_positions(run.config, run.truth, cmd, tool), predicted_std(J, result.covariance)


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.mark.parametrize("grid, truth_knots, seed", [((6, 5, 4), 50.0, 0), ((9, 7, 6), 25.0, 2)])
def test_smoothed_motions_predict_unseen_points_better_and_their_u_covers(tmp_path, grid, truth_knots, seed):
    """The shipped walk-through's grid (default knots: one cubic per axis, the resolution check inflating u) and a
    denser one with a finer truth: the smoothed motions' unseen error is at most half the default's, and the
    stated u covers it (RMS error / RMS u within 0.5-2, >= 95 % within 3 u)."""
    data, run = _campaign(tmp_path, grid, truth_knots, seed)
    plain = identify_volumetric(data, VolumetricOptions(tool_offsets_mm=TOOLS))
    smooth = identify_volumetric(data, VolumetricOptions(tool_offsets_mm=TOOLS, smoothing="auto"))
    assert smooth.model.config.knot_spacing_mm == smooth_knot_spacing(data.commands_mm)
    assert smooth.model.config.knot_spacing_mm < 0.5 * plain.model.config.knot_spacing_mm
    s = smooth.fit.smoothing
    assert s["method"] == "restricted maximum likelihood" and 0 < s["effective_parameters"] < len(smooth.fit.names)
    assert any(n.startswith("smoothness prior on the error motions") for n in smooth.fit.notes)
    assert smooth.resolution is None  # (the prior, not the knots, sets what the motions hold)
    e_plain, _ = _unseen(plain, run)
    e, u = _unseen(smooth, run)
    assert _rms(e) <= 0.5 * _rms(e_plain), (_rms(e), _rms(e_plain))
    seen = u > 1e-9
    assert 0.5 <= _rms(e) / _rms(u) <= 2.0, _rms(e) / _rms(u)
    assert np.mean(np.abs(e[seen]) <= 3 * u[seen]) >= 0.95
    assert np.isfinite(smooth.fit.condition_number)


def test_the_prior_separates_motion_shapes_the_positions_alone_cannot(tmp_path):
    """Knots finer than the commanded positions: without the prior the campaign is refused (a spline richer than
    the positions); with it, every motion is separable (none held) -- the prior holds the shapes between the
    positions, the readings their trends."""
    from olti_drake.errors import InputError

    data, _ = _campaign(tmp_path, (6, 5, 4), 50.0, 0)
    with pytest.raises(InputError, match="distinct positions"):
        identify_volumetric(data, VolumetricOptions(tool_offsets_mm=TOOLS, knot_spacing_mm=25.0))
    res = identify_volumetric(data, VolumetricOptions(tool_offsets_mm=TOOLS, knot_spacing_mm=25.0, smoothing="auto"))
    assert res.held == {} and res.model.config.knot_spacing_mm == 25.0


def test_smoothing_on_the_command_line(tmp_path, capsys):
    from olti_drake.cli.verbs import main

    data, _ = _campaign(tmp_path, (6, 5, 4), 50.0, 0)
    path = tmp_path / "campaign_0.csv"
    out = tmp_path / "vol.json"
    assert main(["identify", str(path), "--model", "volumetric", "--tool-offsets-mm", "0,0,100;80,0,100;0,80,140",
                 "--smoothing", "auto", "--out", str(out)]) == 0
    import json

    doc = json.loads(out.read_text())
    assert doc["smoothing"]["method"] == "restricted maximum likelihood"
    assert doc["representation"]["knot_spacing_mm"] == smooth_knot_spacing(data.commands_mm)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["identify", str(path), "--model", "volumetric", "--smoothing", "-3", "--out", str(tmp_path / "b.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--smoothing" in err[0], err
