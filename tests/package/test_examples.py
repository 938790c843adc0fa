"""The example and the benchmark baseline agree with ``olti simulate`` (mm, deg).

The example assembles the campaign diagram by hand; the benchmark computes the
same readings in numpy without Drake. Both must match the CLI's diagram.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from olti_drake.sim.campaign import prepare, run_campaign
from olti_drake.sim.scenario import Scenario

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "simulate_paper_campaign.py"
BENCH = ROOT / "benchmarks" / "bench_simulate.py"


def run(*args, cwd):
    """Run a Python command line; fail the test with its stderr if it fails."""
    proc = subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def data_lines(path):
    """The CSV without its ``#`` comment lines (those name the writer)."""
    return [line for line in Path(path).read_bytes().splitlines() if not line.startswith(b"#")]


@pytest.fixture(scope="module")
def cli_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    run("-m", "olti_drake.cli", "simulate", "--out", out, cwd=out)
    return out


def test_example_equals_olti_simulate(tmp_path, cli_out):
    # Both written on this machine in this run: the same bytes (across machines: tests/numeric_files.py).
    out = run(EXAMPLE, "--out", tmp_path / "ex", cwd=tmp_path)
    assert "wrote" in out
    assert data_lines(tmp_path / "ex" / "campaign.csv") == data_lines(cli_out / "campaign.csv")
    ours = json.loads((tmp_path / "ex" / "truth.json").read_text())
    theirs = json.loads((cli_out / "truth.json").read_text())
    assert ours.keys() == theirs.keys()
    assert ours == theirs


def test_example_default_out_dir_and_meshcat(tmp_path):
    # --meshcat starts a headless Meshcat server; stdin is not a tty, so it does not wait.
    out = run(EXAMPLE, "--meshcat", cwd=tmp_path)
    assert "meshcat: http" in out
    assert (tmp_path / "example_out" / "campaign.csv").is_file()


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_simulate", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_numpy_baseline_equals_diagram():
    # The baseline draws its noise in one batch, the diagram per reading: compare noise-free.
    scenario = Scenario()
    scenario.interferometer.noise = False
    scenario.interferometer.quantization = False
    setup = prepare(scenario)
    campaign = run_campaign(setup).columns
    base = load_bench().numpy_baseline(setup)
    for key in ("reflector", "theta1_deg", "theta2_deg", "theta4_deg", "valid"):
        np.testing.assert_allclose(base[key], campaign[key], rtol=0, atol=1e-9, err_msg=key)
    valid = campaign["valid"] > 0
    assert valid.sum() > 0.9 * valid.size
    np.testing.assert_allclose(base["displacement_mm"][valid], campaign["displacement_mm"][valid],
                               rtol=0, atol=1e-9)
    assert np.isnan(base["displacement_mm"][~valid]).all()
