"""Trials on many cores and beyond one machine (issue 26 item 5): one joblib entry point
(:func:`olti_drake.estimation.trials.run_trials`) for the Monte Carlo, seeds spawned from the root seed.

The Monte Carlo result is the same bit for bit (one run, one machine) with 1 worker (in process), 2 loky worker
processes and the Dask backend on a local cluster of 2 worker processes, for a SCARA identification (batched
solver) and a six-axis robot from a model file (its Drake plant rebuilt in each worker); each block of trials
draws its own errors; the workers die with their parent; bad backends are refused in one line. The docs'
commands (docs/trials.md) run here. Units: mm and degrees.
"""

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import olti_drake
from olti_drake.errors import InputError
from olti_drake.estimation import uncertainty
from olti_drake.estimation.trials import TrialTask, check_backend, run_trials
from olti_calls import error_line

ROOT = Path(__file__).resolve().parents[2]
CAMPAIGN = ROOT / "data" / "paper000" / "campaign.csv"


def _build(spec):
    return {"scale": spec, "pid": os.getpid()}


def _draw(built, seed, arg):
    """A trial: three numbers from its own seed (times the built scale), and where it ran."""
    return built["scale"] * np.random.default_rng(seed).standard_normal(3) + (arg or 0), built["pid"]


def test_trial_seeds_depend_on_the_trial_only_not_on_workers_or_batch():
    task = TrialTask(_build, 2.0, _draw)
    here = run_trials(task, 9, seed=11, workers=1)
    there = run_trials(task, 9, seed=11, workers=2, batch=4, args=[0.0] * 9)
    assert np.array_equal(np.array([r[0] for r in here]), np.array([r[0] for r in there]))
    assert {r[1] for r in here} == {os.getpid()} and os.getpid() not in {r[1] for r in there}
    values = np.array([r[0] for r in here])
    assert len(np.unique(values[:, 0])) == 9  # every trial its own seed
    # A SeedSequence root is continued: two calls of 4 and 5 trials are the 9 trials of one call.
    root = np.random.SeedSequence(11)
    parts = run_trials(task, 4, root, workers=1) + run_trials(task, 5, root, workers=2)
    assert np.array_equal(values, np.array([r[0] for r in parts]))
    assert not np.array_equal(values, np.array([r[0] for r in run_trials(task, 9, seed=12, workers=1)]))


@pytest.fixture(scope="module")
def scara():
    """A random quarter of the shipped paper-000 campaign, error-map model: the batched Monte Carlo."""
    from olti_drake.estimation.identification import IdentificationOptions, Identifier
    from olti_drake.io.csvio import load_campaign
    from olti_drake.model.budget import ReadingErrors, paper000_budget

    data = load_campaign(CAMPAIGN)
    keep = np.sort(np.random.default_rng(3).permutation(len(data))[:len(data) // 4])
    ident = Identifier(data.subset(keep), IdentificationOptions(model="errormap"))
    return ident, ident.solve().x, ReadingErrors(paper000_budget())


def test_monte_carlo_is_bit_identical_on_one_two_workers_and_a_dask_cluster(scara):
    pytest.importorskip("distributed", reason="the Dask backend needs dask[distributed] (pip install .[dev])")
    ident, x, errors = scara
    n = 2 * uncertainty.BATCH + 17  # three blocks: both workers busy
    one = uncertainty.monte_carlo(ident, x, errors, trials=n, seed=3, workers=1).samples
    two = uncertainty.monte_carlo(ident, x, errors, trials=n, seed=3, workers=2).samples
    # run_trials makes (and closes) a LocalCluster of 2 single-threaded worker processes.
    dask = uncertainty.monte_carlo(ident, x, errors, trials=n, seed=3, workers=2, backend="dask").samples
    assert one.shape == (n, len(x)) and np.all(np.isfinite(one))
    assert np.array_equal(one, two) and np.array_equal(one, dask)
    assert len(np.unique(one[:, 0])) == n  # no block repeats another's errors
    # The Monte Carlo is a Monte Carlo of this problem: its spread is the linear method's within the sampling error.
    u = np.sqrt(np.diag(uncertainty.linear_covariance(ident, x, errors)))
    assert np.all(np.abs(one.std(axis=0, ddof=1) / u - 1) < 5 / np.sqrt(2 * (n - 1)))


def test_monte_carlo_does_not_depend_on_the_campaign_row_order(scara):
    """The same readings in another file order draw the same errors (by their content: uncertainty.content_order),
    so every trial, not only the spread, is the same to rounding; before, the errors went by row (12 % apart)."""
    from olti_drake.estimation.identification import IdentificationOptions, Identifier

    ident, x, errors = scara
    perm = np.random.default_rng(8).permutation(len(ident.data))
    other = Identifier(ident.data.subset(perm), IdentificationOptions(model="errormap"))
    y = other.solve().x
    a = uncertainty.monte_carlo(ident, x, errors, trials=40, seed=5, workers=1).samples
    b = uncertainty.monte_carlo(other, y, errors, trials=40, seed=5, workers=1).samples
    assert np.allclose(x, y, rtol=0, atol=1e-9)
    assert np.abs(a - b).max() < 1e-8, np.abs(a - b).max()
    c = uncertainty.monte_carlo(ident, x, errors, trials=40, seed=6, workers=1).samples
    assert np.abs(a - c).max() > 1e-4  # (another seed: other errors, the check can fail)


def test_a_robot_from_a_model_file_is_rebuilt_once_per_worker_with_its_plant(monkeypatch):
    """A calibration without batched residuals (trial by trial), whose measurement holds a Drake plant: the chain
    pickles without it and each worker reads it again from the model file; the samples are the same bits."""
    from olti_drake.estimation.calibration import Calibration, SolverOptions
    from olti_drake.io.budget import default_budget
    from olti_drake.model.budget import ReadingErrors
    from olti_drake.model.chain import load_serial_chain
    from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign,
                                         synthetic_truth)

    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    copy = pickle.loads(pickle.dumps(chain))
    assert copy.plant is not None and copy.plant is not chain.plant and copy.tool_frame_index == chain.tool_frame_index
    assert np.array_equal(copy.fixed_mm, chain.fixed_mm) and copy.joint_names == chain.joint_names
    truth = synthetic_truth(chain, seed=5, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, 60, seed=6, ranges_deg=np.tile([-90.0, 90.0], (6, 1)), noise_mm=0.0005)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="dh", tool_offset_mm=(40.0, -25.0, 60.0))
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    cal = Calibration(meas, SolverOptions(), find_gauge(meas), "synthetic UR5")
    x = cal.fit().x
    errors = ReadingErrors(default_budget("scara"))
    monkeypatch.setattr(uncertainty, "BATCH", 8)  # the blocks are cut here, in the parent: 3 of them
    one = uncertainty.monte_carlo(cal, x, errors, trials=20, seed=2, workers=1).samples
    two = uncertainty.monte_carlo(cal, x, errors, trials=20, seed=2, workers=2).samples
    assert np.all(np.isfinite(one)) and np.array_equal(one, two)
    assert len(np.unique(one[:, np.argmax(one.std(axis=0))])) == 20  # (a gauge-held column stays put)


_W = np.random.default_rng(0).uniform(0.5, 2.0, 80)


def _layout_cost(layout):
    """A synthetic layout cost with local minima (weights plus a spread term), for the design's search."""
    return float(np.sum(_W[layout]) + 1e-6 * np.var(np.asarray(layout, float) ** 2))


def _slot_costs(others, trial):
    return np.array([_layout_cost(list(others) + [int(t)]) for t in trial])


def test_the_design_starts_run_on_workers_with_the_same_result():
    """The coordinate exchange's starts are trials: drawn in the parent from the one generator of the seed (the
    starts of today), searched anywhere; the same layout, cost, count and progress with 1 and 2 workers."""
    from olti_drake.estimation.serial_design import coordinate_exchange

    cand = np.random.default_rng(1).uniform(-1000.0, 1000.0, (80, 3))
    runs = []
    for workers in (1, 2):
        seen = []
        out = coordinate_exchange(cand, np.arange(5, 80), 4, _layout_cost, _slot_costs, seed=3, starts=3,
                                  max_sweeps=4, min_separation_mm=200.0, progress=lambda *a: seen.append(a),
                                  workers=workers)
        runs.append((out, seen))
    (best, cost, evaluations), seen = runs[0]
    assert runs[0] == runs[1] and evaluations > 3 and {s[0] for s in seen} == {0, 1, 2}
    assert cost == _layout_cost(best) and min(s[2] for s in seen) == cost


class _Unpicklable:
    def __reduce__(self):
        raise TypeError("cannot pickle '_Unpicklable' object")


def test_bad_backends_and_tasks_are_refused_in_one_line(monkeypatch):
    import importlib.util

    with pytest.raises(InputError, match=r"^--backend spark: not one of loky, dask, ray$"):
        check_backend("spark")
    with pytest.raises(InputError, match=r"^--scheduler applies to --backend dask"):
        check_backend("loky", "tcp://10.0.0.5:8786")
    with pytest.raises(InputError, match=r"^--workers 3: the cluster of --scheduler tcp://h:8786 has its own"):
        check_backend("dask", "tcp://h:8786", 3)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name in ("distributed", "ray")
                        else real(name, *a))
    with pytest.raises(InputError, match=r"^--backend dask needs the 'dask\[distributed\]' package: pip install "
                                         r"olti_drake\[cluster\]$"):
        check_backend("dask")
    with pytest.raises(InputError, match=r"^--backend ray needs the 'ray' package: pip install ray$"):
        check_backend("ray")
    monkeypatch.undo()
    task = TrialTask(_build, _Unpicklable(), _draw)
    with pytest.raises(InputError, match=r"^the trials cannot leave this process: _Unpicklable does not pickle"):
        run_trials(task, 2, workers=2)


def _doc_block():
    """docs/trials.md's first ```bash block: the commands run on this machine."""
    text = (ROOT / "docs" / "trials.md").read_text(encoding="utf-8")
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line.split() for line in block.splitlines() if line.startswith("olti ")]


def test_trials_doc_block(tmp_path, monkeypatch, capsys):
    """The doc's commands (in this process: its loky workers are already up): one and two workers write the same
    uncertainties (JSON floats round-trip: the same bits); a backend option refused in one line."""
    from olti_drake.cli import main

    (tmp_path / "data").symlink_to(ROOT / "data")
    monkeypatch.chdir(tmp_path)
    for argv in _doc_block():
        assert main(argv[1:]) == 0, (argv, capsys.readouterr().err)
    u1, u2 = (json.loads((tmp_path / f).read_text()) for f in ("u1.json", "u2.json"))
    assert u1["parameters"]["std"] == u2["parameters"]["std"] and u1["trials"] == u2["trials"] == 1000
    capsys.readouterr()
    code = main(["uncertainty", "dh.json", "data/paper000/campaign.csv", "--method", "mc", "--scheduler",
                 "tcp://127.0.0.1:1", "--out", "x.json"])
    err = capsys.readouterr().err
    error_line(code, err)
    assert err.startswith("error: --scheduler applies to --backend dask"), err
    assert not (tmp_path / "x.json").exists()
    code = main(["design", "dh.json", "--regions", "data/regions_paper000.yaml", "--workers", "2", "--out", "d.json"])
    err = capsys.readouterr().err
    error_line(code, err)
    assert err.startswith("error: --workers: a SCARA design searches its starts in this process"), err
    assert not (tmp_path / "d.json").exists()


_KILL_SCRIPT = """
import os, sys, time
from olti_drake.estimation.trials import TrialTask, run_trials

def build(spec):
    return None

def work(built, seed, arg):
    if arg:
        time.sleep(120)
    time.sleep(0.5)
    return os.getpid()

task = TrialTask(build, None, work)
print(" ".join(str(p) for p in sorted(set(run_trials(task, 4, 0, workers=2)))), flush=True)
run_trials(task, 2, 0, workers=2, args=[1, 1])
"""


def test_workers_die_with_their_parent():
    """Hang class of issue 24: ``kill -9`` of the process running the trials must not leave its workers on the
    cores. loky's workers ask the kernel to end them with their parent (PR_SET_PDEATHSIG, die_with_parent)."""
    p = subprocess.Popen([sys.executable, "-c", _KILL_SCRIPT], stdout=subprocess.PIPE, text=True)
    try:
        workers = [int(v) for v in p.stdout.readline().split()]
        assert workers and all(_running(w) for w in workers)  # (the trials may all have run on one)
        time.sleep(0.5)  # the sleeping trials started
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(_running(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_running(w) for w in workers), "a worker outlived its parent"


def _running(pid: int) -> bool:
    """Alive and not a zombie (an orphan's exit may wait for a reaper)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except FileNotFoundError:
        return False
