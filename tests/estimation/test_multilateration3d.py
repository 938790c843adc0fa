"""The machine tool in 3D (issue 15 items 1-2): the 3D campaign reader (``z_cmd_mm``, ``tool``), the
simulated 3D campaign on pan/tilt heads, and 3D self-calibrating multilateration (001 Eq. 2-6 in R^3)."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import UnidentifiableError
from olti_drake.estimation.multilateration import load_machine_campaign, machine_campaign
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d
from olti_calls import error_line, olti_sub


@pytest.fixture(scope="module")
def campaign3d():
    """A small 3D campaign: 60 targets (5 x 4 x 3 grid), 5 heads, seeded."""
    return simulate_machine_campaign_3d(Machine3DScenario(seed=4))


def test_3d_reader_gives_dim_commands_and_tools(tmp_path, campaign3d):
    cols, truth = campaign3d
    path = tmp_path / "c3.csv"
    write_machine_campaign(cols, path)
    data = load_machine_campaign(path)
    assert data.dim == 3 and data.commands_mm.shape == (60, 3) and data.n_stations == 5
    np.testing.assert_allclose(data.commands_mm, truth["commands_mm"], atol=1e-6)
    assert data.tool.tolist() == [0] * 60
    flat = {k: v for k, v in cols.items() if k not in ("z_cmd_mm", "tool")}
    assert machine_campaign(flat).dim == 2  # without z_cmd_mm: the 2D campaign of formats.md


def test_3d_reader_refuses_a_target_whose_rows_disagree_naming_both_lines(tmp_path, campaign3d):
    cols, _ = campaign3d
    path = tmp_path / "c3.csv"
    write_machine_campaign(cols, path)
    lines = path.read_text().splitlines()
    header = [k for k, line in enumerate(lines) if line.startswith("station")][0]
    names = lines[header].split(",")
    # The second reading of target 0 (station 1's row) gets another z command, then another tool.
    row = header + 1 + 60
    for column, value in (("z_cmd_mm", "7.5"), ("tool", "1")):
        bad = list(lines)
        fields = bad[row].split(",")
        fields[names.index(column)] = value
        bad[row] = ",".join(fields)
        (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
        with pytest.raises(InputError, match=rf"bad.csv:{row + 1}: target 0 has command .* on line {header + 2}"):
            load_machine_campaign(tmp_path / "bad.csv")


def test_3d_simulation_is_seeded_and_reads_the_volumetric_truth(campaign3d):
    cols, truth = campaign3d
    again, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=4))
    np.testing.assert_array_equal(cols["displacement_mm"], again["displacement_mm"])
    other, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=5))
    assert not np.allclose(cols["displacement_mm"], other["displacement_mm"], equal_nan=True)
    # The reading is the true distance (truth targets and heads) minus the dead path, to the budget's noise.
    T, P, L0 = (np.asarray(truth[k]) for k in ("targets_mm", "stations_mm", "dead_paths_mm"))
    i, j, ok = cols["target"], cols["station"], cols["valid"] == 1
    model = np.linalg.norm(T[i] - P[j], axis=1) - L0[j]
    from olti_drake.model.budget import paper001_budget

    pose = paper001_budget().combined("pose")  # the head's radial error motion moves the beam origin (001 Table 4)
    assert ok.mean() > 0.95 and np.abs(model - cols["displacement_mm"])[ok].max() < 2e-3 + 5 * pose
    # The truth is not the commands: the 21 motions move the tool by micrometres.
    dev = np.asarray(truth["targets_mm"]) - (np.asarray(truth["commands_mm"]) + np.asarray(truth["tool_offsets_mm"])[0])
    assert 1e-3 < np.abs(dev).max() < 0.2


def _subset(cols, targets=None, stations=None):
    """The readings of the chosen targets and stations, indices renumbered 0.. in the given order."""
    keep = np.ones(len(cols["target"]), dtype=bool)
    out = dict(cols)
    for key, chosen in (("target", targets), ("station", stations)):
        if chosen is None:
            continue
        chosen = np.asarray(chosen)
        keep &= np.isin(cols[key], chosen)
        renumber = np.full(cols[key].max() + 1, -1)
        renumber[chosen] = np.arange(len(chosen))
        out[key] = renumber[cols[key]]
    return {k: v[keep] for k, v in out.items()}


def _aligned_truth(res, truth):
    from olti_drake.estimation.multilateration import align_to_commands

    return align_to_commands(np.asarray(truth["targets_mm"]), res.nominal_mm)


def test_3d_recovers_targets_within_the_stated_uncertainty():
    """Criterion: the target errors (truth moved into the best-fit gauge) against the stated covariance give
    chi^2/dof in [0.7, 1.4] (dof = 3 N_i - 6 = 354, sd 0.075), at least 99 % of the coordinates within 3 u
    and none beyond 4.5 u -- with the covariance from the residual variance and from the 001 Table 4 budget
    (the simulation's own noise: reading and head pose); the heads are found within 4 u."""
    from olti_drake.estimation.multilateration import align_to_commands, multilaterate
    from olti_drake.model.budget import paper001_budget

    cols, truth = simulate_machine_campaign_3d(Machine3DScenario(seed=2, grid=(6, 5, 4)))
    data = machine_campaign(cols)
    for budget in (None, paper001_budget()):
        res = multilaterate(data, budget=budget)
        assert res.targets_mm.shape == (120, 3) and res.stations_mm.shape == (5, 3)
        assert "three translations and three rotations" in res.gauge
        T, S = align_to_commands(np.asarray(truth["targets_mm"]), res.nominal_mm, np.asarray(truth["stations_mm"]))
        e = (res.targets_mm - T).ravel()
        C = res.fit.covariance[:e.size, :e.size]
        chi2 = e @ np.linalg.pinv(C, rcond=1e-10, hermitian=True) @ e / (e.size - 6)
        assert 0.7 < chi2 < 1.4
        assert np.abs(e).max() > 1e-4  # errors exist: the test could fail
        z = np.abs(res.targets_mm - T) / res.targets_std_mm
        assert np.mean(z < 3) >= 0.99 and z.max() < 4.5
        u_S = np.asarray(res.to_dict()["uncertainty"]["stations_mm"])
        assert np.all(np.abs(res.stations_mm - S) < 4 * u_S)


def test_3d_two_tools_are_two_targets_per_command_and_their_offset_is_found():
    from olti_drake.estimation.multilateration import multilaterate
    from olti_drake.model.volumetric3d import MachineConfig

    cfg = MachineConfig(tool_offsets_mm=((0.0, 0.0, 100.0), (80.0, 0.0, 60.0)))
    cols, truth = simulate_machine_campaign_3d(Machine3DScenario(seed=3, config=cfg, tools=(0, 1)))
    data = machine_campaign(cols)
    assert data.n_tools == 2 and data.n_targets == 120
    np.testing.assert_array_equal(data.commands_mm[:60], data.commands_mm[60:])
    res = multilaterate(data)
    t = res.tool_offsets_mm[1] - res.tool_offsets_mm[0]
    assert np.abs(t - [80.0, 0.0, -40.0]).max() < 0.01  # estimated from the readings, relative to tool 0
    assert any("tool offsets estimated" in n for n in res.fit.notes)
    e = res.targets_mm - _aligned_truth(res, truth)
    assert np.abs(e).max() < 5 * res.targets_std_mm.max()
    given = multilaterate(data, options=_options(tool_offsets_mm=cfg.tool_offsets_mm))
    assert given.to_dict()["tool_offsets_mm"] == [list(v) for v in cfg.tool_offsets_mm]


def _options(**kw):
    from olti_drake.estimation.multilateration import MultilaterationOptions

    return MultilaterationOptions(**kw)


def test_3d_counting_condition(campaign3d):
    from olti_drake.estimation.multilateration import counting_bound, multilaterate

    assert counting_bound(4, 3) == 10.0 and counting_bound(5, 3) == 7.0 and counting_bound(3, 3) == np.inf
    assert counting_bound(3, 2) == 6.0  # the 2D form (3 N_j - 3)/(N_j - 2)
    cols, _ = campaign3d
    spread = np.random.default_rng(0).permutation(60)  # targets over the volume, not on one plane
    with pytest.raises(UnidentifiableError, match=r"N_i > \(4 N_j - 6\)/\(N_j - 3\) = 10"):
        multilaterate(machine_campaign(_subset(cols, spread[:10], [0, 1, 2, 3])))
    assert multilaterate(machine_campaign(_subset(cols, spread[:11], [0, 1, 2, 3]))).targets_mm.shape == (11, 3)
    with pytest.raises(UnidentifiableError, match="3 station position.*needs at least 4"):
        multilaterate(machine_campaign(_subset(cols, None, [0, 1, 2])))


def test_3d_coplanar_stations_are_refused_by_name():
    from olti_drake.estimation.multilateration import multilaterate

    heads = [[-250.0, -200.0, -100.0], [650.0, -180.0, -100.0], [620.0, 520.0, -100.0], [-220.0, 480.0, -100.0],
             [200.0, 150.0, -100.0]]
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=1, heads_mm=heads))
    with pytest.raises(UnidentifiableError, match="the 5 stations lie on one plane") as e:
        multilaterate(machine_campaign(cols))
    assert "P4_z_mm" in e.value.names
    # Tilted but still one plane: refused alike; one head raised by 150 mm: solved.
    tilted = [[x, y, -100.0 + 0.2 * x - 0.1 * y] for x, y, _ in heads]
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=1, heads_mm=tilted))
    with pytest.raises(UnidentifiableError, match="lie on one plane"):
        multilaterate(machine_campaign(cols))
    heads[4][2] = -250.0
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=1, heads_mm=heads))
    assert multilaterate(machine_campaign(cols)).fit.converged_by


def test_3d_targets_on_one_plane_or_line_are_refused_by_name(campaign3d):
    from olti_drake.estimation.multilateration import multilaterate

    cols, _ = campaign3d
    data = machine_campaign(cols)
    for name, pick in (("plane", data.commands_mm[:, 2] == 0.0), ("plane", data.commands_mm[:, 0] == 0.0),
                       ("line", (data.commands_mm[:, 2] == 0.0) & (data.commands_mm[:, 1] == 0.0))):
        chosen = np.flatnonzero(pick)
        with pytest.raises(UnidentifiableError, match=f"target command positions lie on one plane|"
                                                      f"{len(chosen)} targets with") as e:
            multilaterate(machine_campaign(_subset(cols, chosen)))
        assert name == "line" or "lie on one plane" in str(e.value)


def test_3d_station_with_too_few_targets_is_refused_by_name(campaign3d):
    from olti_drake.estimation.multilateration import multilaterate

    cols = dict(campaign3d[0])
    drop = (cols["station"] == 2) & (cols["target"] >= 4)
    cols["valid"] = np.where(drop, 0, cols["valid"])
    with pytest.raises(UnidentifiableError, match="station 2 reads 4 target.*at least 5") as e:
        multilaterate(machine_campaign(cols))
    assert e.value.names == ["P2_x_mm", "P2_y_mm", "P2_z_mm", "L0_2_mm"]


def test_3d_gauge_first_three_states_itself_and_agrees_up_to_a_rigid_motion(campaign3d):
    from olti_drake.estimation.multilateration import multilaterate

    data = machine_campaign(campaign3d[0])
    a = multilaterate(data)
    b = multilaterate(data, options=_options(gauge="first-three"))
    assert "constrained to it" in b.gauge
    np.testing.assert_allclose(b.targets_mm[0], data.commands_mm[0] + b.tool_offsets_mm[0], atol=1e-9)
    # Same readings, same distances: every inter-target distance agrees.
    d = [np.linalg.norm(r.targets_mm[:, None] - r.targets_mm[None], axis=-1) for r in (a, b)]
    assert np.abs(d[0] - d[1]).max() < 1e-7
    with pytest.raises(InputError, match="best-fit, first-three for a 3D campaign"):
        multilaterate(data, options=_options(gauge="first-two"))


def test_3d_jacobian_is_sparse_one_target_one_station_per_reading(campaign3d):
    from olti_drake.estimation.multilateration import Multilateration

    ml = Multilateration(machine_campaign(campaign3d[0]))
    r, J = ml.residuals(ml.x0)
    assert J.shape == (len(r), 3 * 60 + 4 * 5) and J.nnz == 7 * len(r)
    # Against finite differences of the residual.
    x, k = ml.x0.copy(), 3 * 7 + 1
    x[k] += 1e-6
    np.testing.assert_allclose((ml.residuals(x)[0] - r) / 1e-6, J[:, k].toarray().ravel(), atol=1e-5)


def test_cli_multilaterate_and_uncertainty_in_3d(tmp_path, campaign3d):
    import json

    cols, truth = campaign3d
    camp = tmp_path / "c3.csv"
    write_machine_campaign(cols, camp)
    out = olti_sub("multilaterate", camp, "--out", tmp_path / "r.json")
    assert out.returncode == 0, out.stderr
    assert "3D" in out.stdout and "station 4: (" in out.stdout
    res = json.loads((tmp_path / "r.json").read_text())
    assert np.shape(res["targets_mm"]) == (60, 3) and np.shape(res["stations_mm"]) == (5, 3)
    assert np.shape(res["uncertainty"]["targets_mm"]) == (60, 3) and "three rotations" in res["gauge"]
    assert res["tools"] == [0] * 60 and res["tool_offsets_mm"] == [[0.0, 0.0, 0.0]]
    # Table 4 budget (the default): 99 % of the coordinates within 3 u of the truth, in the same gauge.
    from olti_drake.estimation.multilateration import align_to_commands

    T = align_to_commands(np.asarray(truth["targets_mm"]), np.asarray(res["commands_mm"]))
    assert np.mean(np.abs(np.asarray(res["targets_mm"]) - T) < 3 * np.asarray(res["uncertainty"]["targets_mm"])) >= 0.99
    lin = olti_sub("uncertainty", tmp_path / "r.json", camp, "--method", "linear", "--out", tmp_path / "u.json",
                   "--map", tmp_path / "u.png")
    assert lin.returncode == 0, lin.stderr
    u = json.loads((tmp_path / "u.json").read_text())
    np.testing.assert_allclose(u["targets_mm"], res["uncertainty"]["targets_mm"], rtol=1e-6)
    assert (tmp_path / "u.png").stat().st_size > 10_000
    mc = olti_sub("uncertainty", tmp_path / "r.json", camp, "--method", "mc", "--trials", "200", "--seed", "1",
                  "--out", tmp_path / "m.json")
    assert mc.returncode == 0, mc.stderr
    ratio = np.asarray(json.loads((tmp_path / "m.json").read_text())["targets_mm"]) / np.asarray(u["targets_mm"])
    assert 0.75 < np.median(ratio) < 1.25  # Monte Carlo agrees with the linear propagation (200 trials)


def test_cli_3d_options_are_checked_against_the_campaign(tmp_path, campaign3d):
    camp = tmp_path / "c3.csv"
    write_machine_campaign(campaign3d[0], camp)
    for extra, says in ((["--gauge", "first-two"], "--gauge first-two: a 3D campaign"),
                        (["--stations-mm", "0,0;1,1;2,2;3,3;4,4"], "--stations-mm: .* 3 coordinates")):
        out = olti_sub("multilaterate", camp, "--out", tmp_path / "r.json", *extra)
        error_line(out.returncode, out.stderr)
        assert not (tmp_path / "r.json").exists()
        import re

        assert re.search(says, out.stderr), out.stderr


def test_3d_result_reads_back_and_is_reported(tmp_path, campaign3d):
    import json

    from olti_drake.estimation.multilateration import load_result, multilaterate

    camp = tmp_path / "c3.csv"
    write_machine_campaign(campaign3d[0], camp)
    data = load_machine_campaign(camp)
    res = multilaterate(data)
    path = tmp_path / "r.json"
    path.write_text(json.dumps(res.to_dict()))
    back = load_result(path)
    assert np.shape(back["targets_mm"]) == (60, 3) and back["gauge_kind"] == "best-fit"
    doc = res.to_dict()
    doc["stations_mm"] = np.asarray(doc["stations_mm"])[:, :2].tolist()  # 2D stations in a 3D result
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="r.json: key 'stations_mm'"):
        load_result(path)
    path.write_text(json.dumps(res.to_dict()))
    out = olti_sub("report", path, "--campaign", camp, "--out", tmp_path / "rep")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "rep" / "report.html").stat().st_size > 10_000
    # The campaign digest covers the z commands and tools: a campaign that differs only there is refused.
    from olti_drake.io.csvio import campaign_digest

    moved = machine_campaign({**campaign3d[0], "z_cmd_mm": campaign3d[0]["z_cmd_mm"] + 1.0})
    assert campaign_digest(moved)["sha256"] != campaign_digest(machine_campaign(campaign3d[0]))["sha256"]
    retooled = machine_campaign({**campaign3d[0], "tool": campaign3d[0]["target"] % 2})
    assert campaign_digest(retooled)["sha256"] != campaign_digest(machine_campaign(campaign3d[0]))["sha256"]


def test_3d_heads_aim_open_loop_from_their_estimates():
    """001 Eq. (1) in 3D: the head points at the commanded tool point from its ESTIMATED centre, so an
    estimate off by more than the cat's eye's acceptance (1 mm) loses the beam; the truth's µm do not."""
    good, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=6, head_error_mdeg=0.0))
    bad, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=6, head_error_mdeg=0.0,
                                                            station_estimate_sigma_um=3000.0))
    assert good["valid"].mean() > 0.95 and bad["valid"].mean() < 0.6
