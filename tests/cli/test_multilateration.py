"""Self-calibrating multilateration of paper 001 (Eq. 2-6) on simulated machine-tool campaigns."""

import json

import numpy as np
import pytest

from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.budget import paper001_budget
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.estimation.calibration import UnidentifiableError
from olti_drake.model.machine import MachineScenario, simulate_machine_campaign, square_targets
from olti_drake.estimation.multilateration import (MultilaterationOptions, align_to_commands, load_machine_campaign,
                                        machine_campaign, multilaterate)
from olti_calls import olti_sub


def _campaign(tmp_path, name="c.csv", **kw):
    """Simulated campaign through its CSV file (formats.md) and the truth."""
    cols, truth = simulate_machine_campaign(MachineScenario(**kw))
    path = tmp_path / name
    write_machine_campaign(cols, path)
    return load_machine_campaign(path), truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_targets_stations_and_dead_paths_recovered_within_3_sigma(tmp_path, seed):
    data, truth = _campaign(tmp_path, seed=seed)
    res = multilaterate(data, budget=paper001_budget())  # the simulator's budget: 001 Table 4
    cmd = np.array(truth["commands_mm"])
    targets, stations = align_to_commands(truth["targets_mm"], cmd, truth["stations_mm"])
    # Every target within 3 standard uncertainties of its position (the 2-norm u of 001 Fig. 14).
    err = np.hypot(*(res.targets_mm - targets).T)
    assert np.all(err < 3 * np.hypot(*res.targets_std_mm.T)), (err / np.hypot(*res.targets_std_mm.T)).max()
    # ... and the uncertainty is neither too small nor inflated: normalized errors have unit RMS.
    z = (res.targets_mm - targets) / res.targets_std_mm
    assert 0.6 < np.sqrt(np.mean(z ** 2)) < 1.4
    n_i, n_j = len(cmd), len(stations)
    std = res.fit.std
    zs = (res.stations_mm - stations) / std[2 * n_i:2 * n_i + 2 * n_j].reshape(-1, 2)
    zd = (res.dead_paths_mm - np.array(truth["dead_paths_mm"])) / std[2 * n_i + 2 * n_j:]
    assert np.abs(zs).max() < 3.5 and np.abs(zd).max() < 3.5
    # The machine's error is well above the uncertainty: the method sees it.
    dev = np.hypot(*(targets - cmd).T)
    assert dev.max() > 3 * np.hypot(*res.targets_std_mm.T).max()


def test_noise_free_campaign_is_recovered_exactly():
    quiet = InterferometerOptions(noise=False, quantization=False, cosine_error=False, beam_loss=False)
    cols, truth = simulate_machine_campaign(MachineScenario(interferometer=quiet))
    res = multilaterate(machine_campaign(cols))  # in memory: a file would round readings to 1e-9 mm
    targets, stations = align_to_commands(truth["targets_mm"], truth["commands_mm"], truth["stations_mm"])
    assert res.targets_mm == pytest.approx(targets, abs=1e-9)
    assert res.stations_mm == pytest.approx(stations, abs=1e-9)
    assert res.dead_paths_mm == pytest.approx(truth["dead_paths_mm"], abs=1e-9)


def test_first_two_gauge(tmp_path):
    data, _ = _campaign(tmp_path)
    res = multilaterate(data, MultilaterationOptions(gauge="first-two"))
    c = data.commands_mm
    assert res.targets_mm[0] == pytest.approx(c[0], abs=1e-12)
    e = c[1] - c[0]
    d = res.targets_mm[1] - c[0]
    assert e[0] * d[1] - e[1] * d[0] == pytest.approx(0.0, abs=1e-9)
    assert "target 0" in res.gauge
    # The two gauges describe the same shape: equal after moving one into the other's frame.
    best = multilaterate(data)
    assert align_to_commands(res.targets_mm, c) == pytest.approx(best.targets_mm, abs=1e-7)


def test_two_stations_are_rejected(tmp_path):
    data, _ = _campaign(tmp_path, stations_mm=[[-120.0, -80.0], [220.0, -60.0]])
    with pytest.raises(UnidentifiableError, match="at least 3"):
        multilaterate(data)


def test_too_few_targets_are_rejected(tmp_path):
    # 3 stations need N_i > (3*3 - 3)/(3 - 2) = 6: a 6-target square perimeter is not enough.
    data, _ = _campaign(tmp_path, size_mm=40.0, step_mm=20.0)
    assert data.n_targets == 8
    multilaterate(data)
    cols, _ = simulate_machine_campaign(MachineScenario(size_mm=40.0, step_mm=20.0))
    keep = cols["target"] < 6
    path = tmp_path / "six.csv"
    write_machine_campaign({k: v[keep] for k, v in cols.items()}, path)
    with pytest.raises(UnidentifiableError, match=r"N_i > \(3 N_j - 3\)/\(N_j - 2\) = 6"):
        multilaterate(load_machine_campaign(path))


def test_stations_collinear_with_the_targets_are_rejected():
    # Eleven targets on the X axis, three stations on the same line: distances say nothing across it.
    targets = np.column_stack([np.arange(0.0, 101.0, 10.0), np.zeros(11)])
    stations = np.array([[-100.0, 0.0], [200.0, 0.0], [300.0, 0.0]])
    i, j = np.tile(np.arange(11), 3), np.repeat(np.arange(3), 11)
    cols = {"station": j, "target": i, "x_cmd_mm": targets[i, 0], "y_cmd_mm": targets[i, 1],
            "displacement_mm": np.hypot(*(targets[i] - stations[j]).T) - 50.0}
    with pytest.raises(UnidentifiableError, match="not identifiable") as e:
        multilaterate(machine_campaign(cols))
    assert any(n.endswith("_y_mm") for n in e.value.names) and "one line" in str(e.value)


def test_loader_errors_name_file_line_and_column(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("station,target,x_cmd_mm,y_cmd_mm\n0,0,0,0\n")
    with pytest.raises(ValueError, match="bad.csv.*displacement_mm"):
        load_machine_campaign(bad)
    bad.write_text("station,target,x_cmd_mm,y_cmd_mm,displacement_mm\n0,0,0,0,0\n1,0,5,0,1\n")
    with pytest.raises(ValueError, match=r"bad.csv:3: target 0 has command \(5, 0\)"):
        load_machine_campaign(bad)


def test_cli_writes_the_formats_result(tmp_path):
    cols, _ = simulate_machine_campaign(MachineScenario())
    write_machine_campaign(cols, tmp_path / "c.csv")
    r = olti_sub("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", "--stations-mm",
                 "-120,-80;220,-60;50,240", expect=0)
    out = json.loads((tmp_path / "r.json").read_text())
    assert out["format"] == "olti-multilateration/1"
    assert len(out["targets_mm"]) == len(square_targets()) and len(out["stations_mm"]) == 3
    assert len(out["uncertainty"]["targets_mm"]) == len(out["targets_mm"]) and out["gauge"]
    assert "U (k = 2)" in r.stdout


def test_uncertainty_verb_on_a_multilateration_result(tmp_path):
    cols, _ = simulate_machine_campaign(MachineScenario())
    write_machine_campaign(cols, tmp_path / "c.csv")
    olti_sub("multilaterate", tmp_path / "c.csv", "--out", tmp_path / "r.json", expect=0)
    out = {}
    for method in ("linear", "mc"):
        olti_sub("uncertainty", tmp_path / "r.json", tmp_path / "c.csv", "--method", method, "--trials", "1000",
                 "--map", tmp_path / f"{method}.png", "--out", tmp_path / f"{method}.json", expect=0)
        out[method] = json.loads((tmp_path / f"{method}.json").read_text())
        assert (tmp_path / f"{method}.png").stat().st_size > 5000
    lin, mc = (np.array(out[m]["targets_mm"]) for m in ("linear", "mc"))
    assert lin.shape == (len(square_targets()), 2)
    assert mc / lin == pytest.approx(1.0, abs=0.12)  # 1000 trials: ~2 % scatter of a std, plus nonlinearity
    assert out["mc"]["expanded"]["k"] == 2
    # 1000 trials are too few for a reliable 95 % interval (JCGM 101 §7.2.2: 10^4/(1 - p)): omitted, and said so.
    assert "coverage_interval" not in out["mc"]
    assert any("coverage intervals not reported" in n and "200000" in n for n in out["mc"]["notes"])


# -- trust: duplicated rows, implausible solutions, residual against the budget -----------------------------
def test_duplicated_row_is_refused_naming_both_lines(tmp_path):
    cols, _ = simulate_machine_campaign(MachineScenario())
    write_machine_campaign(cols, tmp_path / "c.csv")
    lines = (tmp_path / "c.csv").read_text(encoding="utf-8").splitlines()
    row = next(i for i, l in enumerate(lines) if l and not l.startswith("#")) + 2  # first data row, 1-based
    (tmp_path / "d.csv").write_text("\n".join(lines + [lines[row - 1]]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"d.csv:{len(lines) + 1}: row identical in every column to line {row}"):
        load_machine_campaign(tmp_path / "d.csv")


def test_implausible_solution_is_named_and_residual_checked_against_the_budget(tmp_path):
    from olti_drake.estimation.multilateration import Multilateration
    from olti_drake.model.budget import Budget, Contributor

    data, _ = _campaign(tmp_path)
    ml = Multilateration(data)
    x = ml.x0.copy()
    assert ml.implausible(x) == []
    n_i = data.n_targets
    x[2 * n_i] += 1e6  # station 0 a kilometre away
    x[0] += 50.0  # target 0 half the 100 mm square off its command
    problems = ml.implausible(x)
    assert any(p.startswith("station 0 lies") for p in problems) and any(p.startswith("target 0") for p in problems)
    # The simulator's budget (001 Table 4) explains the residual; one a hundred times smaller does not.
    assert multilaterate(data, budget=paper001_budget()).fit.warnings == []
    tiny = Budget(name="tiny", contributors=[Contributor("u", "", 1.0, "nm", 1.0, "B", "reading")])
    res = multilaterate(data, budget=tiny)
    assert len(res.fit.warnings) == 1 and "budget 'tiny'" in res.fit.warnings[0]
    assert res.to_dict()["warnings"] == res.fit.warnings and res.to_dict()["campaign"]["readings"] == len(data)


def test_uncertainty_map_of_a_multilateration_result_colours_each_target_by_its_U(tmp_path):
    from figure_capture import captured_figures

    from olti_drake.cli import main

    cols, _ = simulate_machine_campaign(MachineScenario())
    write_machine_campaign(cols, tmp_path / "c.csv")
    assert main(["multilaterate", str(tmp_path / "c.csv"), "--out", str(tmp_path / "r.json")]) == 0
    with captured_figures() as figs:
        assert main(["uncertainty", str(tmp_path / "r.json"), str(tmp_path / "c.csv"), "--method", "linear",
                     "--map", str(tmp_path / "u.png"), "--out", str(tmp_path / "u.json")]) == 0
    u = np.array(json.loads((tmp_path / "u.json").read_text())["targets_mm"])
    ax = figs["u.png"].axes[0]
    sc = ax.collections[0]
    np.testing.assert_allclose(sc.get_array(), 2e3 * np.hypot(*u.T), rtol=1e-9)  # U (k = 2), µm
    np.testing.assert_allclose(sc.get_offsets(), load_machine_campaign(tmp_path / "c.csv").commands_mm)
    assert f"max {2e3 * np.hypot(*u.T).max():.1f} µm" in ax.get_title()
