"""Uncertainty of the identification (000 §5; JCGM 100 linear, JCGM 101 Monte Carlo) and `olti uncertainty`.

The key check is against the thing the uncertainty claims to describe: the spread of the estimates
over many *independent* simulated campaigns of the paper-000 experiment (same robot, same plan,
new reading noise each time). With M campaigns the sample standard deviation has a relative standard
error of about 1/sqrt(2(M - 1)) (normal data); per parameter we allow 3.5 of those.
Units: mm and degrees.
"""

import dataclasses
import json
import os

import numpy as np
import scipy.sparse as sp
import pytest
from figure_capture import annotations, captured_figures, errorbar, legend_labels

from olti_drake.io.budget import load_budget
from olti_drake.model.budget import Budget, ReadingErrors
from olti_drake.sim.campaign import prepare, simulate_vectorized, write_campaign
from olti_drake.estimation.identification import IdentificationOptions, Identifier, identify
from olti_drake.sim.scenario import Scenario
from olti_drake.estimation.uncertainty import (BATCH, ROUND_BATCHES, draw_by_content, linear_covariance,
                                    monte_carlo, prediction_std, uncertainty_dict)
from olti_drake.report.validation import campaign_data, random_commands
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: Independent campaigns and Monte Carlo trials of the key test.
M_CAMPAIGNS, MC_TRIALS = 300, 1000
#: Standard errors allowed (two-sided) per parameter.
Z = 3.5
SEED = 20240601


def _rel_se(n: int) -> float:
    """Relative standard error of a sample standard deviation of n normal values."""
    return 1.0 / np.sqrt(2.0 * (n - 1))


def _agree(ratio, rel_se) -> np.ndarray:
    """Per-parameter: does ratio = s_a / s_b agree with 1 within Z relative standard errors?"""
    return np.abs(np.asarray(ratio) - 1.0) <= Z * rel_se


@pytest.fixture(scope="module")
def setup():
    return prepare(Scenario())  # the paper-000 experiment, budget 000 Table 2


@pytest.fixture(scope="module")
def campaigns(setup):
    """Estimates (M, n) of M independent campaigns (same setup and truth, new noise), error-map model."""
    X = []
    for i in range(M_CAMPAIGNS):
        data = campaign_data(simulate_vectorized(setup, np.random.default_rng([SEED, i])))
        X.append(identify(data, IdentificationOptions(model="errormap")).x)
    return np.array(X)


@pytest.fixture(scope="module")
def first(setup):
    """The first campaign's Identifier, its solution x and the simulator's budget as reading errors."""
    data = campaign_data(simulate_vectorized(setup, np.random.default_rng([SEED, 0])))
    ident = Identifier(data, IdentificationOptions(model="errormap"))
    return ident, ident.solve().x, ReadingErrors(setup.budget)


@pytest.fixture(scope="module")
def small(setup):
    """A random quarter of a campaign's readings: the same kind of problem, 4x cheaper trials (MC mechanics)."""
    data = campaign_data(simulate_vectorized(setup, np.random.default_rng([SEED, 2])))
    keep = np.sort(np.random.default_rng([SEED, 3]).permutation(len(data))[:len(data) // 4])
    ident = Identifier(data.subset(keep), IdentificationOptions(model="errormap"))
    return ident, ident.solve().x, ReadingErrors(setup.budget)


@pytest.fixture(scope="module")
def linear_std(first):
    ident, x, errors = first
    return np.sqrt(np.diag(linear_covariance(ident, x, errors)))


@pytest.fixture(scope="module")
def mc(first):
    ident, x, errors = first
    return monte_carlo(ident, x, errors, trials=MC_TRIALS, seed=7, workers=1)


def _doubled(budget: Budget) -> Budget:
    return dataclasses.replace(budget, contributors=[dataclasses.replace(c, value=2 * c.value)
                                                     for c in budget.contributors])


def test_uncertainty_predicts_the_spread_of_independent_campaigns(setup, campaigns, first, linear_std, mc):
    ident, x, errors = first
    names = ident.names
    empirical = campaigns.std(axis=0, ddof=1)
    se_lin = _rel_se(M_CAMPAIGNS)  # the linear value is exact for its model: only the campaigns scatter
    se_mc = np.hypot(_rel_se(M_CAMPAIGNS), _rel_se(MC_TRIALS))
    r_lin = empirical / linear_std
    r_mc = empirical / mc.samples.std(axis=0, ddof=1)
    print(f"\nindependent campaigns (M = {M_CAMPAIGNS}) / linear: {r_lin.min():.3f}..{r_lin.max():.3f}, "
          f"/ MC ({MC_TRIALS} trials): {r_mc.min():.3f}..{r_mc.max():.3f} "
          f"(allowed {Z} x {se_lin:.3f} / {se_mc:.3f})")
    # Every parameter: L1, L2, every J1 and J2 node (J1 gauge-fixed identically in every campaign), P, d0.
    groups = {"L": ("L1_mm", "L2_mm"), "J1": ("J1_",), "J2": ("J2_",), "P": ("P",), "d0": ("d0_",)}
    for group, prefixes in groups.items():
        sel = np.array([n.startswith(prefixes) for n in names])
        assert sel.any(), group
        for ratio, se, label in ((r_lin, se_lin, "linear"), (r_mc, se_mc, "MC")):
            bad = sel & ~_agree(ratio, se)
            assert not bad.any(), f"{label}: {[(n, round(r, 3)) for n, r, b in zip(names, ratio, bad) if b]}"

    # The simulator adds the reading and pose terms as noise but not u31/u32 (beam_direction_noise is off:
    # the beam direction errors are modelled physically); the budget keeps them for the cosine error,
    # D u_psi^2 / sqrt(2) < 1 µm against the ~16 µm reading uncertainty -- a negligible part of the variance.
    assert not setup.scenario.interferometer.beam_direction_noise
    D = ident.beam_lengths(x)
    u_all = errors.std(D)
    u_simulated = np.hypot(setup.budget.combined("reading"), setup.budget.combined("pose"))
    assert np.max(np.sqrt(u_all**2 - u_simulated**2)) < 1e-3
    assert np.max(u_all / u_simulated) < 1.005  # vs the Z x 1/sqrt(2(M - 1)) = 14 % allowed above

    # The check can fail: a budget with doubled values predicts twice the spread, and the campaigns say no.
    doubled = np.sqrt(np.diag(linear_covariance(ident, x, ReadingErrors(_doubled(setup.budget)))))
    r2 = empirical / doubled
    assert np.all(np.abs(r2 - 0.5) <= Z * se_lin * 0.5 + 1e-3), (r2.min(), r2.max())
    assert not _agree(r2, se_lin).any()


def test_mc_agrees_with_linear_on_the_paper_problem(first, linear_std, mc):
    ident, _, _ = first
    ratio = mc.samples.std(axis=0, ddof=1) / linear_std
    worst = int(np.argmax(np.abs(np.log(ratio))))
    print(f"\nMC ({MC_TRIALS} trials) / linear: worst {ratio[worst]:.3f} at {ident.names[worst]}, "
          f"range {ratio.min():.3f}..{ratio.max():.3f}")
    assert mc.samples.shape == (MC_TRIALS, len(ident.names))
    assert np.all(np.abs(ratio - 1) < 0.10), ratio


def test_mc_is_reproducible_and_independent_of_workers(small):
    ident, x, errors = small
    a = monte_carlo(ident, x, errors, trials=2 * BATCH + 17, seed=3, workers=1)
    b = monte_carlo(ident, x, errors, trials=2 * BATCH + 17, seed=3, workers=1)
    c = monte_carlo(ident, x, errors, trials=2 * BATCH + 17, seed=3, workers=2)
    d = monte_carlo(ident, x, errors, trials=2 * BATCH + 17, seed=4, workers=1)
    assert a.samples.shape == (2 * BATCH + 17, len(x))
    assert np.array_equal(a.samples, b.samples)
    assert np.array_equal(a.samples, c.samples)
    assert not np.array_equal(a.samples, d.samples)
    assert len(np.unique(a.samples[:, 0])) == len(a.samples)  # no batch repeats another's errors


def test_adaptive_stops_reports_and_does_not_depend_on_workers(small):
    ident, x, errors = small
    # The mechanics on 50 % intervals (quartiles: ~5 rounds); 95 % endpoints need ~14 rounds (28 000 trials).
    a = monte_carlo(ident, x, errors, seed=5, workers=1, adaptive=True, tolerance_digits=1, coverage=0.5)
    n = len(a.samples)
    # Two workers, and the cap exactly where the first run became stable: the same trials, still converged
    # (stable at the cap is converged, JCGM 101 §7.9).
    runs = [a, monte_carlo(ident, x, errors, seed=5, workers=2, adaptive=True, tolerance_digits=1, coverage=0.5,
                           max_trials=n)]
    assert runs[1].converged
    assert a.converged and n >= 2 * BATCH * ROUND_BATCHES and n % (BATCH * ROUND_BATCHES) == 0
    assert a.intervals_adequate  # stable endpoints make the intervals reportable whatever the count
    assert any(f"{n} trials" in note for note in a.notes), a.notes
    assert len(np.unique(a.samples[:, 0])) == n  # later rounds draw new errors
    assert np.array_equal(a.samples, runs[1].samples)


def _flat(layout, names):
    """The formats.md layout (result keys and shapes) back to a vector in the order of ``names``."""
    v = [layout["L1_mm"], layout["L2_mm"]]
    for axis in ("J1", "J2"):
        v += layout["error_map"][axis]["forward_deg"] + layout["error_map"][axis]["reverse_deg"]
    v += list(np.ravel(layout["reflectors_mm"])) + list(layout["dead_paths_mm"])
    assert len(v) == len(names)
    return np.array(v, dtype=float)


def test_coverage_interval_contains_estimate_and_expanded_is_k_times_std(setup, first, mc):
    ident, x, _ = first
    std = mc.samples.std(axis=0, ddof=1)
    u = uncertainty_dict(ident, std, "mc", setup.budget, k=2.5, samples=mc.samples, coverage=0.95,
                         extra={"trials": len(mc.samples)})
    assert u["k"] == 1 and u["expanded"]["k"] == 2.5 and u["trials"] == MC_TRIALS
    np.testing.assert_allclose(_flat(u, ident.names), std, rtol=1e-12)
    np.testing.assert_allclose(_flat(u["expanded"], ident.names), 2.5 * std, rtol=1e-12)
    lo, hi = (_flat(u["coverage_interval"][s], ident.names) for s in ("low", "high"))
    assert u["coverage_interval"]["p"] == 0.95
    assert np.all(lo < x) and np.all(x < hi)
    # A 95 % interval of a near-normal output spans about ±1.96 u.
    np.testing.assert_allclose((hi - lo) / (2 * 1.96 * std), 1.0, atol=0.15)


def test_prediction_std_matches_the_mc_spread_of_positions(first, mc):
    ident, x, errors = first
    model = ident.split(x)[0]
    cs = random_commands(300, [SEED, 9], tuple(model.map1.grid_deg[[0, -1]]), tuple(model.map2.grid_deg[[0, -1]]))
    cov = linear_covariance(ident, x, errors)
    linear = prediction_std(ident, cov, x, cs.commands)
    spread = ident.robot0.positions_batch(cs.commands, mc.samples[:, :ident.n_robot]).std(axis=0, ddof=1)
    ratio = spread / linear
    print(f"\npredicted-position spread (MC) / prediction_std: {ratio.min():.3f}..{ratio.max():.3f}")
    assert np.all(np.abs(ratio - 1) < 0.10), (ratio.min(), ratio.max())


# -- the command -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def files(setup, tmp_path_factory):
    """A campaign.csv and its error-map result.json in a fresh directory."""
    from olti_drake.io.csvio import load_campaign
    from olti_drake.io.result import write_result

    d = tmp_path_factory.mktemp("unc")
    csv, _ = write_campaign(simulate_vectorized(setup, np.random.default_rng([SEED, 1])), str(d))
    result = str(d / "result.json")
    write_result(identify(load_campaign(csv), IdentificationOptions(model="errormap")), result)
    return d, csv, result


def _same_layout(a, b, path=""):
    """Same keys and shapes (recursively) in a and b."""
    assert set(a) == set(b), (path, sorted(a), sorted(b))
    for k in a:
        if isinstance(a[k], dict):
            _same_layout(a[k], b[k], f"{path}.{k}")
        else:
            assert np.shape(a[k]) == np.shape(b[k]), f"{path}.{k}"


def _values_layout(result: dict) -> dict:
    """The result's values in the uncertainty layout (formats.md: map values without the grid)."""
    out = {k: result[k] for k in ("L1_mm", "L2_mm", "reflectors_mm", "dead_paths_mm")}
    out["error_map"] = {a: {k: v for k, v in m.items() if k != "grid_deg"} for a, m in result["error_map"].items()}
    return out


@pytest.mark.parametrize("method", ["linear", "mc"])
def test_cli_writes_uncertainty_json(files, method, capsys):
    from olti_drake.cli import main
    from olti_drake.io.csvio import load_campaign
    from olti_drake.estimation.identification import identifier_at_result

    d, csv, result = files
    out = d / f"unc_{method}.json"
    extra = ["--trials", "300", "--seed", "11", "--workers", "1"] if method == "mc" else []
    assert main(["uncertainty", result, csv, "--method", method, "--k", "2",
                                     "--out", str(out)] + extra) == 0
    text = capsys.readouterr().out
    assert "L1: u =" in text and "J2 map nodes u =" in text and "U (k = 2) max" in text and str(out) in text
    u = json.loads(out.read_text())
    r = json.loads(open(result).read())
    assert u["k"] == 1 and u["method"] == method and u["budget"] == "paper 000 Table 2"
    values = _values_layout(r)
    _same_layout(values, {k: u[k] for k in values})
    _same_layout(values, {k: u["expanded"][k] for k in values})
    assert u["expanded"]["k"] == 2.0
    assert 0.0158 < u["reading_std_median_mm"] <= u["reading_std_max_mm"] < 0.0159  # 000 Table 2: ~16 µm
    assert u["elapsed_s"] >= 0 and u["prediction_expanded_mm"]["max"] > u["prediction_expanded_mm"]["mean"] > 0
    ident, x = identifier_at_result(result, load_campaign(csv))
    errors = ReadingErrors(load_budget(os.path.join(ROOT, "data", "budget_paper000.yaml")))
    if method == "linear":
        expect = np.sqrt(np.diag(linear_covariance(ident, x, errors)))
    else:
        assert u["trials"] == 300 and u["seed"] == 11
        # 300 trials cannot give reliable 95 % intervals (JCGM 101 §7.2.2 asks 10^4/(1 - p)): omitted, said so.
        assert "coverage_interval" not in u and any("200000" in n for n in u["notes"])
        expect = monte_carlo(ident, x, errors, trials=300, seed=11, workers=1).samples.std(axis=0, ddof=1)
    np.testing.assert_allclose(u["parameters"]["std"], expect, rtol=1e-9)
    np.testing.assert_allclose(_flat(u, ident.names), expect, rtol=1e-9)


def test_cli_map_figures(files, capsys):
    from olti_drake.cli import main

    d, csv, result = files
    png, maps = d / "map.png", d / "maps.png"
    with captured_figures() as figs:
        assert main(["uncertainty", result, csv, "--method", "linear", "--out", str(d / "u.json"),
                     "--map", str(png), "--maps", str(maps), "--budget",
                     os.path.join(ROOT, "data", "budget_paper001.yaml")]) == 0
    for p in (png, maps):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    u = json.loads((d / "u.json").read_text())
    res = json.loads(open(result).read())
    assert u["budget"] == "paper 001 Table 4"
    # The map's colours are the U (k = 2) the file summarizes; the reflectors are the result's P0..P2.
    fig = figs["map.png"]
    U = np.concatenate([np.ma.filled(ax.collections[0].get_array(), np.nan).ravel() for ax in fig.axes[:2]])
    pe = u["prediction_expanded_mm"]
    assert np.nanmax(U) == pytest.approx(1e3 * pe["max"]) and np.nanmean(U) == pytest.approx(1e3 * pe["mean"])
    assert "linear, budget paper 001 Table 4" in fig._suptitle.get_text()
    for ax in fig.axes[:2]:
        marks = annotations(ax)
        assert sorted(marks) == ["P0", "P1", "P2"] and marks["P1"] == pytest.approx(tuple(res["reflectors_mm"][1]))
    # The maps: the result's identified values with the file's u (k = 1) as error bars, no truth.
    for ax, axis in zip(figs["maps.png"].axes, ("J1", "J2")):
        for block, name in (("forward", "positive (+1)"), ("reverse", "negative (-1)")):
            _, y, half = errorbar(ax, f"identified, {name}, error bar u (k = 1), linear")
            np.testing.assert_allclose(y, 1e3 * np.array(res["error_map"][axis][f"{block}_deg"]))
            np.testing.assert_allclose(half, 1e3 * np.array(u["error_map"][axis][f"{block}_deg"]), rtol=1e-6)
        assert not any(lab.startswith("truth") for lab in legend_labels(ax))
    # The named budget is the one propagated, not only the one reported (001 Table 4 differs from 000 Table 2).
    from olti_drake.io.csvio import load_campaign
    from olti_drake.estimation.identification import identifier_at_result

    ident, x = identifier_at_result(result, load_campaign(csv))
    for name, expect in (("paper001", True), ("paper000", False)):
        errors = ReadingErrors(load_budget(os.path.join(ROOT, "data", f"budget_{name}.yaml")))
        std = np.sqrt(np.diag(linear_covariance(ident, x, errors)))
        assert np.allclose(u["parameters"]["std"], std, rtol=1e-9) == expect, name


def test_cli_bad_input_is_one_line_exit_2(files, tmp_path):
    d, csv, result = files
    missing = str(tmp_path / "no_budget.yaml")
    r = olti_sub("uncertainty", result, csv, "--method", "linear", "--budget", missing, "--out",
                 str(tmp_path / "u.json"))
    error_line(r.returncode, r.stderr)
    assert missing in r.stderr and not (tmp_path / "u.json").exists()

    from olti_drake.cli import main
    before = open(csv, "rb").read()
    assert main(["uncertainty", result, csv, "--method", "linear", "--out", csv]) == 2  # never overwrite an input
    assert open(csv, "rb").read() == before
    bad = tmp_path / "bad.yaml"
    bad.write_text("contributors:\n- {symbol: u1, value: 1.0, unit: um, acts_on: reading, distribution: gauss}\n")
    assert main(["uncertainty", result, csv, "--method", "mc", "--budget", str(bad), "--out",
                 str(tmp_path / "u.json")]) == 2
    r = olti_sub("uncertainty", result, csv, "--method", "mc", "--trials", "1", "--out", str(tmp_path / "u.json"))
    error_line(r.returncode, r.stderr, "--trials")  # refused by argparse


# -- gaps an audit's mutations showed (each test fails on its mutation) ------------------------------
@pytest.fixture(scope="module")
def first_result(setup):
    """The first campaign's identification as ``olti identify`` reports it (residual-based std, k = 1)."""
    data = campaign_data(simulate_vectorized(setup, np.random.default_rng([SEED, 0])))
    return identify(data, IdentificationOptions(model="errormap"))


def test_result_std_predicts_the_spread_of_independent_campaigns(campaigns, first_result):
    """The standard uncertainties result.json carries (residual variance through the Jacobian) against the spread
    of 300 independent campaigns: every parameter within Z relative standard errors (the campaigns' 1/sqrt(2(M-1))
    plus the residual variance's own ~1/sqrt(2 dof), dof ~ 1000). A doubled posterior variance (x1.41) fails."""
    empirical = campaigns.std(axis=0, ddof=1)
    ratio = empirical / first_result.std
    se = np.hypot(_rel_se(M_CAMPAIGNS), _rel_se(first_result.n_readings - len(first_result.names)))
    print(f"\nindependent campaigns / result std: {ratio.min():.3f}..{ratio.max():.3f}, median {np.median(ratio):.3f}")
    assert _agree(ratio, se).all(), [(n, round(r, 3)) for n, r in zip(first_result.names, ratio) if abs(r - 1) > Z * se]
    assert abs(np.median(ratio) - 1) < 0.08  # the median over 49 parameters is tighter still


def test_mc_trials_are_each_re_solved_to_their_own_minimum(small):
    """Each Monte Carlo trial is the least-squares solution of its own readings: rebuild the first trials'
    readings from the batch seeds and solve them from scratch with the identifier's LM. The LM stops at a
    relative cost change of 1e-12 (parameters to ~1e-6 u: measured 3e-6 u); one linearized step instead of
    the re-solve leaves 1e-4..2e-4 u (measured) -- the threshold 3e-5 u lies between."""
    from olti_drake.io.csvio import CampaignData

    ident, x, errors = small
    mc = monte_carlo(ident, x, errors, trials=4, seed=3, workers=1)
    model = ident.residual_rows(x[None], np.zeros(len(ident.data)))[0][0]  # the model's own readings at x
    E = draw_by_content(errors, np.random.default_rng(np.random.SeedSequence(3).spawn(1)[0]), ident.beam_lengths(x),
                        model, 4)  # (the errors in the readings' content order, as every trial draws them)
    std = Identifier(ident.data, IdentificationOptions(model="errormap")).solve().std
    d = ident.data
    opts = IdentificationOptions(grid1_deg=ident.robot0.map1.grid_deg, grid2_deg=ident.robot0.map2.grid_deg)
    for t in range(4):
        trial = CampaignData(d.reflector, d.commands, model + E[t], d.line, "trial")
        exact = Identifier(trial, opts).solve().x
        assert np.max(np.abs(mc.samples[t] - exact) / std) < 3e-5, t


def test_adaptive_stopping_rule_needs_estimate_u_and_both_endpoints_stable():
    """JCGM 101 §7.9.4: 2 s ≤ δ for the estimate, u and both interval endpoints; δ = ½ 10^l from u's digits."""
    from olti_drake.estimation.uncertainty import _stable

    rng = np.random.default_rng(1)
    steady = [np.array([[10.0], [1.23], [8.0], [12.0]]) + 1e-5 * rng.standard_normal((4, 1)) for _ in range(4)]
    assert _stable(steady, 2)
    for row in range(4):  # any of the four scattering by 0.05 (> δ = 0.005 for u = 1.23, 2 digits) is unstable
        shaky = [h.copy() for h in steady]
        for i, h in enumerate(shaky):
            h[row] += 0.05 * (-1) ** i
        assert not _stable(shaky, 2), row


def test_adaptive_cap_reports_not_converged_and_omits_intervals(small):
    from olti_drake.estimation.uncertainty import round_trials

    ident, x, errors = small
    capped = monte_carlo(ident, x, errors, seed=5, workers=1, adaptive=True, tolerance_digits=4,
                         max_trials=2 * round_trials(0.95))
    assert len(capped.samples) == 2 * round_trials(0.95)
    assert not capped.converged and not capped.intervals_adequate
    assert any("NOT stable" in n for n in capped.notes), capped.notes
    fixed = monte_carlo(ident, x, errors, trials=300, seed=5, workers=1)
    assert fixed.converged and not fixed.intervals_adequate  # 300 < 10^4/(1 - 0.95)


def test_each_contributor_is_drawn_with_its_own_distribution():
    """Normal: excess kurtosis 0; uniform (rectangular): -1.2. With 200 000 draws the sample excess kurtosis
    has a standard error of sqrt(24/n) = 0.011 (normal), so ±0.06 separates the two by far."""
    from olti_drake.model.budget import Contributor

    def kurtosis(distribution):
        b = Budget(name=distribution, contributors=[Contributor("u", "", 3.0, "um", 1.0, "B", "reading",
                                                                distribution)])
        e = ReadingErrors(b).draw(np.random.default_rng(0), np.full(1000, 500.0), 200).ravel()
        assert e.std() == pytest.approx(3e-3, rel=0.01)
        return np.mean((e - e.mean()) ** 4) / e.var() ** 2 - 3.0

    assert abs(kurtosis("normal")) < 0.06
    assert abs(kurtosis("uniform") + 1.2) < 0.06


def test_monte_carlo_refuses_trials_that_do_not_converge(small, monkeypatch):
    """Reading errors of 10 mm (a budget in the wrong unit) drive trials beyond where the chord iteration
    re-solves them. Gauss-Newton at each trial's own point re-solves them (each within 1e-5 of the parameters'
    u of the identifier's LM on the trial's readings from scratch: measured 5e-7..5e-6); cut to one step it does
    not, and the trials that did not converge refuse the Monte Carlo (before, their NaN or unconverged rows went
    into the standard uncertainties silently)."""
    from olti_drake.estimation import uncertainty
    from olti_drake.estimation.calibration import FitRefused
    from olti_drake.io.csvio import CampaignData
    from olti_drake.model.budget import Contributor

    ident, x, _ = small
    wrong = ReadingErrors(Budget(name="mm", contributors=[Contributor("u", "", 10.0, "mm", 1.0, "B", "reading")]))
    mc = monte_carlo(ident, x, wrong, trials=2, seed=1, workers=1)
    model = ident.residual_rows(x[None], np.zeros(len(ident.data)))[0][0]
    E = draw_by_content(wrong, np.random.default_rng(np.random.SeedSequence(1).spawn(1)[0]), ident.beam_lengths(x),
                        model, 2)
    d = ident.data
    opts = IdentificationOptions(grid1_deg=ident.robot0.map1.grid_deg, grid2_deg=ident.robot0.map2.grid_deg)
    for t in range(2):
        exact = Identifier(CampaignData(d.reflector, d.commands, model + E[t], d.line, "trial"), opts).solve()
        assert np.max(np.abs(mc.samples[t] - exact.x) / exact.std) < 1e-5, t
    monkeypatch.setattr(uncertainty, "RESCUE_ITERATIONS", 1)
    with pytest.raises(FitRefused, match=r"Monte Carlo refused, nothing written -- \d+ of 50 trials did not"):
        monte_carlo(ident, x, wrong, trials=50, seed=1, workers=1)


def test_a_trial_the_chord_iteration_does_not_converge_is_re_solved_at_its_own_point(small):
    """The chord iteration steps with B fixed at the estimate; where a trial's own curvature differs enough (a
    weakly determined, curved direction: B H has an eigenvalue near 2, met on a five-axis errormap campaign) its
    steps stop shrinking. Forced here with B twice too large (every eigenvalue of B H at 2, rate 1): without the
    rescue the trials are given up (NaN), with it (Gauss-Newton at the trial's own point) they reach the same
    solutions as with the right B, to 1e-6 of the parameters' spread."""
    from olti_drake.estimation import uncertainty

    ident, x, errors = small
    n = len(x)
    model, cols, _ = ident.residual_rows(x[None], np.zeros(len(ident.data)))
    k, m = cols.shape
    scatter = sp.csr_matrix((np.ones(k * m), (np.arange(k * m), cols.ravel())), shape=(k * m, n))
    D = model[0] + errors.draw(np.random.default_rng(4), ident.beam_lengths(x), 3)
    B, _ = uncertainty._solution_map(ident, x)
    Q, q = np.zeros((n, n)), np.zeros(n)
    right = uncertainty._solve_trials(ident, x, B, D, q, Q, scatter)
    assert np.all(np.isfinite(right))
    stalled = uncertainty._solve_trials(ident, x, 2.0 * B, D, q, Q, scatter)
    assert np.all(np.isnan(stalled))
    rescued = uncertainty._solve_trials(ident, x, 2.0 * B, D, q, Q, scatter, remap=uncertainty._Remap(ident))
    spread = np.maximum(np.std(right, axis=0), 1e-12)
    assert np.all(np.abs(rescued - right) <= 1e-6 * np.max(spread) + 1e-6 * spread)


def test_a_trial_count_beyond_reason_is_refused_before_any_work(tmp_path):
    """Hang and memory class of issue 24: ``--trials 10000000000`` ran silently for ever. The option has an upper
    bound, and below it the library refuses samples that would not fit in memory, naming the count and the size."""
    from olti_drake.errors import InputError
    from olti_drake.estimation.uncertainty import MAX_SAMPLE_BYTES, _check_sample_size

    result = tmp_path / "r.json"
    olti_sub("identify", "data/paper000/campaign.csv", "--model", "dh", "--out", result, timeout=120, expect=0)
    for trials, message in (("10000000000", "argument --trials: must be a whole number in [2, 100000000]"),
                            ("90000000", "trials 90000000: the Monte Carlo samples of 12 parameters would take")):
        run = olti_sub("uncertainty", result, "data/paper000/campaign.csv", "--method", "mc", "--trials", trials,
                       "--out", tmp_path / "u.json", timeout=120, expect=2)
        assert message in run.stderr, run.stderr
        assert not (tmp_path / "u.json").exists()
    _check_sample_size(MAX_SAMPLE_BYTES // (8 * 49), 49, "trials")  # (just at the bound: taken)
    with pytest.raises(InputError, match="max_trials 10956550: .* 49 parameters"):
        _check_sample_size(MAX_SAMPLE_BYTES // (8 * 49) + 1, 49, "max_trials")
