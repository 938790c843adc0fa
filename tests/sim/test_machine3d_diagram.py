"""The 3D machine-tool campaign as a Drake diagram (issue 15 item 1; olti_drake/sim/machine3d_station.py):
the diagram reads what the numpy twin (model.machine.simulate_machine_campaign_3d) reads, `olti simulate
diagrams/machine_3d.yaml` writes a 3D campaign that `olti multilaterate` and `olti identify --model
volumetric` take, deterministically."""

import json
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d
from olti_drake.model.volumetric3d import MachineConfig
from olti_drake.sim.machine3d_station import (is_machine3d_scenario, load_machine3d_scenario,
                                              run_machine3d_campaign)
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
YAML = os.path.join(ROOT, "diagrams", "machine_3d.yaml")
TOOLS = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0), (0.0, 80.0, 140.0))
SMALL = "{grid: [3, 3, 2], tools: [0, 2]}"


def _scenario(chains=(("X", "Y", "Z"), ()), **options):
    return Machine3DScenario(config=MachineConfig(*chains, tool_offsets_mm=TOOLS), grid=(3, 3, 2), tools=(0, 1, 2),
                             interferometer=InterferometerOptions(**options), seed=4)


@pytest.mark.parametrize("chains", [(("X", "Y", "Z"), ()), (("Z",), ("Y", "X"))], ids=["serial", "table-xy"])
def test_diagram_reads_what_the_numpy_twin_reads(chains):
    """Noise and quantization off: the same rows and readings to 1e-9 mm, the same truth; the heads' own
    errors, estimate errors and three tools are in; serial X-Y-Z and a table carrying X and Y."""
    s = _scenario(chains, noise=False, quantization=False)
    twin, twin_truth = simulate_machine_campaign_3d(s)
    cols, truth = run_machine3d_campaign(s)
    assert set(cols) == set(twin)
    for k in twin:
        if k != "displacement_mm":
            assert np.array_equal(cols[k], twin[k]), k
    assert np.all(cols["valid"] == 1) and len(cols["valid"]) == 3 * 18 * 5
    assert np.max(np.abs(cols["displacement_mm"] - twin["displacement_mm"])) < 1e-9
    assert truth == twin_truth
    # The readings see the volumetric error: not the distances to the commanded tool points.
    P, dead = np.array(truth["stations_mm"]), np.array(truth["dead_paths_mm"])
    i, j = twin["target"], twin["station"]
    nominal = np.array(truth["commands_mm"]) + np.array(TOOLS)[np.array(truth["tools"])]
    off = np.linalg.norm(nominal[i] - P[j], axis=1) - dead[j] - cols["displacement_mm"]
    assert np.max(np.abs(off)) > 1e-3


def test_noisy_readings_differ_from_the_twin_by_the_budget_only():
    """With the budget's noise (separate seeded streams) the diagram and the twin agree to the noise level."""
    s = _scenario(noise=True, quantization=True)
    twin, _ = simulate_machine_campaign_3d(s)
    cols, _ = run_machine3d_campaign(s)
    d = cols["displacement_mm"] - twin["displacement_mm"]
    assert 1e-5 < np.std(d) < 5e-3 and not np.array_equal(cols["displacement_mm"], twin["displacement_mm"])


def test_simulate_same_seed_same_bytes(tmp_path):
    outs = []
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        r = olti_sub("simulate", YAML, "--scenario-text", SMALL, "--seed", seed, "--out", tmp_path / name)
        assert r.returncode == 0, r.stderr
        outs.append([(tmp_path / name / f).read_bytes() for f in ("campaign.csv", "truth.json")])
    assert outs[0] == outs[1]
    assert outs[0][0] != outs[2][0]
    # measurements are never replaced
    r = olti_sub("simulate", YAML, "--scenario-text", SMALL, "--out", tmp_path / "a")
    error_line(r.returncode, r.stderr, "campaign.csv")


def test_shipped_scenario_is_multilaterated_and_identified(tmp_path):
    """`olti simulate diagrams/machine_3d.yaml` -> multilaterate -> identify --model volumetric, against the truth."""
    r = olti_sub("simulate", YAML, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    truth = json.loads((tmp_path / "truth.json").read_text())
    header = [line for line in (tmp_path / "campaign.csv").read_text().splitlines() if not line.startswith("#")][0]
    assert header == "station,target,x_cmd_mm,y_cmd_mm,z_cmd_mm,tool,displacement_mm,valid"
    heads = np.array(truth["stations_mm"])
    assert truth["tool_offsets_mm"] == [list(t) for t in TOOLS] and truth["n_readings"] > 0.9 * 360 * 5

    r = olti_sub("multilaterate", tmp_path / "campaign.csv", "--out", tmp_path / "ml.json")
    assert r.returncode == 0, r.stderr
    ml = json.loads((tmp_path / "ml.json").read_text())
    # its frame best fits the commands plus the tool offsets relative to tool 0
    assert np.max(np.abs(np.array(ml["stations_mm"]) - (heads - TOOLS[0]))) < 0.03

    r = olti_sub("identify", tmp_path / "campaign.csv", "--model", "volumetric", "--tool-offsets-mm",
                 ";".join(",".join(f"{v:g}" for v in t) for t in TOOLS), "--out", tmp_path / "vol.json")
    assert r.returncode == 0, r.stderr
    vol = json.loads((tmp_path / "vol.json").read_text())
    assert vol["format"] == "olti-volumetric/1" and vol["converged"]
    assert vol["residual_rms_mm"] < 3e-3
    assert np.max(np.abs(np.array(vol["tool_offsets_mm"]) - TOOLS)) < 2e-3   # the truth's offsets are exact
    assert np.max(np.abs(np.array(vol["stations_mm"]) - heads)) < 0.03       # origin at tool 0, as the truth


def test_scenario_detection_and_bad_fields(tmp_path):
    assert is_machine3d_scenario(YAML)
    assert not is_machine3d_scenario(os.path.join(ROOT, "diagrams", "six_axis.yaml"))
    assert not is_machine3d_scenario(os.path.join(ROOT, "diagrams", "paper000_scara.yaml"))
    doc = load_machine3d_scenario(YAML)
    assert doc.scenario().config.tools.shape == (3, 3)
    # named scenarios over a base, as the other scenario files
    named = tmp_path / "named.yaml"
    named.write_text(f"small:\n  base: {YAML}\n  grid: [3, 3, 2]\n  tools: [1]\n")
    assert is_machine3d_scenario(named, "small") and not is_machine3d_scenario(named, "other")
    small = load_machine3d_scenario(named, "small").scenario()
    assert small.grid == (3, 3, 2) and small.tools == (1,) and len(small.heads_mm) == 5
    for text, name in (("{tools: [0, 3]}", "tools"), ("{grid: [1, 4, 4]}", "grid"),
                       ("{heads_mm: [[0, 0]]}", "heads_mm"), ("{catseye_axis: [0, 0, 0]}", "catseye_axis"),
                       ("{machine: {travel_mm: {X: [5, 1]}}}", "travel_mm"), ("{seed: -1}", "seed"),
                       ("{interferometer: {acceptance_mm: -1}}", "acceptance_mm"), ("{period_s: 0}", "period_s")):
        with pytest.raises(InputError, match=name):
            load_machine3d_scenario(YAML, None, text).scenario(f"scenario {YAML}")
    r = olti_sub("simulate", named, "--scenario", "small", "--out", tmp_path / "n")
    assert r.returncode == 0 and "90 readings" in r.stdout, r.stderr
    for text, name in (("{grid: [1, 4, 4]}", "grid"), ("{gird: [4, 4, 4]}", "gird"), ("{seed: x}", "machine_3d.yaml"),
                       ("{budget: nope.yaml}", "nope.yaml")):
        r = olti_sub("simulate", YAML, "--scenario-text", text, "--out", tmp_path / "x")
        error_line(r.returncode, r.stderr, name)
        assert not (tmp_path / "x" / "campaign.csv").exists()


def test_olti_run_on_the_simulated_station_writes_what_olti_simulate_writes(tmp_path):
    """`olti run` takes the 3D scenario too (issue 22; its emulated and hardware stations:
    tests/hardware/test_machine3d_run.py): on the scenario's simulated station its log holds the readings `olti
    simulate` writes, in the same columns, followed by the run-log columns."""
    from olti_drake.io.csvio import read_table

    r = olti_sub("run", YAML, "--scenario-text", SMALL, "--out", tmp_path / "r", "--no-fsync")
    assert r.returncode == 0 and "180 of 180 planned readings" in r.stdout, r.stderr
    r = olti_sub("simulate", YAML, "--scenario-text", SMALL, "--out", tmp_path / "s")
    assert r.returncode == 0, r.stderr
    cols = ("station", "target", "x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "tool", "displacement_mm", "valid")
    run, sim = (read_table(tmp_path / d / "campaign.csv", cols) for d in ("r", "s"))
    for k in cols:
        np.testing.assert_allclose(run[k], sim[k], rtol=0, atol=1e-9, err_msg=k)
    header = [x for x in (tmp_path / "r" / "campaign.csv").read_text().splitlines() if not x.startswith("#")][0]
    assert header.startswith(",".join(cols) + ",plan_row,step,session,status,reads,rezeros,time_utc,elapsed_s")
    assert json.loads((tmp_path / "r" / "truth.json").read_text()) == json.loads((tmp_path / "s" / "truth.json")
                                                                                 .read_text())
    r = olti_sub("run", YAML, "--scenario-text", SMALL, "--out", tmp_path / "m", "--meshcat")
    error_line(r.returncode, r.stderr)
    assert r.stderr.startswith("error: --meshcat"), r.stderr
