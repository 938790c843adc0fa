"""``olti uncertainty`` of five-axis results (issue 25, item 5): linear (the identification's covariance) and Monte
Carlo (the campaign's readings re-simulated from the identified model plus seeded errors, re-solved per trial) on
campaigns simulated from a truth outside the model family (:func:`olti_drake.model.five_axis_truth.synthetic_truth`:
harmonic error motions with backlash, identified as maps every 30 deg), through the command line in process."""

import json

import numpy as np
import pytest

from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_truth import synthetic_truth
from tests.estimation.test_five_axis_identify import (SIX_TABLE_STATIONS, TABLE_STATIONS, TRUNNION, distance_campaign,
                                           no_dropped_truth, rtest_campaign, write_five_axis_campaign)
from olti_calls import error_line, olti_in

MACHINE = ("--machine", TRUNNION, "--workpiece-frame", "workpiece", "--tool-frame", "tool")


def identified(folder, cols, *options):
    """(campaign, result) paths: ``cols`` written and identified by ``olti identify --machine``."""
    campaign, result = folder / "campaign.csv", folder / "result.json"
    write_five_axis_campaign(campaign, cols)
    olti_in("identify", campaign, *MACHINE, *options, "--out", result, expect=0)
    return campaign, result


def uncertainty(result, campaign, out, *options) -> dict:
    olti_in("uncertainty", result, campaign, *options, "--out", out, expect=0)
    return json.loads(out.read_text())


def free_location(doc):
    return {n: v for n, v in doc["location_errors"].items() if n not in doc["held"]}


@pytest.fixture(scope="module")
def machine():
    return FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")


@pytest.fixture(scope="module")
def errormap_case(machine, tmp_path_factory):
    """80 commands read from 6 stations on the table (480 distances, 1 µm noise), maps every 30 deg; linear and
    120 Monte Carlo trials."""
    folder = tmp_path_factory.mktemp("errormap")
    truth = no_dropped_truth(synthetic_truth(machine, seed=3))
    campaign, result = identified(folder, distance_campaign(machine, truth, 80, 1, SIX_TABLE_STATIONS, "workpiece"),
                                  "--model", "errormap", "--grid-step-deg", "30")
    linear = uncertainty(result, campaign, folder / "linear.json", "--method", "linear")
    mc = uncertainty(result, campaign, folder / "mc.json", "--method", "mc", "--trials", "120", "--seed", "3")
    return json.loads(result.read_text()), linear, mc, truth


def test_linear_is_the_identifications_covariance(errormap_case):
    doc, linear, _, _ = errormap_case
    own = doc["uncertainty"]
    for n, u in free_location(linear).items():
        assert u == pytest.approx(own["location_errors"][n], rel=1e-6), n
    for name, m in linear["error_motions"].items():  # (the re-solve stops within STEP_FRACTION of each u: with the
        for b in ("forward", "reverse"):             # linear axes identified its covariance differs by 1.1e-6)
            np.testing.assert_allclose(m[b], own["error_motions"][name][b], rtol=2e-6, atol=1e-12)


def test_monte_carlo_agrees_with_linear_and_both_cover_the_truth(errormap_case):
    doc, linear, mc, truth = errormap_case
    assert mc["method"] == "mc" and mc["trials"] == 120 and mc["seed"] == 3
    ratios, z = {}, {}
    for n, v in free_location(doc).items():
        ratios[n] = mc["location_errors"][n] / linear["location_errors"][n]
        z[n] = abs(v - truth.location[n]) / min(mc["location_errors"][n], linear["location_errors"][n])
    assert len(ratios) == 8 and all(0.6 <= r <= 1.6 for r in ratios.values()), ratios
    assert max(z.values()) < 3.0, z
    # every map value has its u, in the result's shapes; the maps' u agree too (median over each branch)
    for name, m in doc["error_motions"].items():
        for b in ("forward", "reverse"):
            lin, sim = np.asarray(linear["error_motions"][name][b]), np.asarray(mc["error_motions"][name][b])
            assert lin.shape == sim.shape == np.shape(m[b]), name
            assert 0.6 <= np.median(sim / lin) <= 1.6, (name, b)
    assert mc["expanded"]["k"] == 2 and mc["expanded"]["location_errors"]["E_X0C_mm"] == pytest.approx(
        2 * mc["location_errors"]["E_X0C_mm"])


# ------------------------------------------------------------------------------------ seeds and row order
def mixed(a: dict, b: dict) -> dict:
    """The rows of two campaigns' columns as one mixed campaign (each kind's cells empty in the other's rows)."""
    n = {k: len(next(iter(c.values()))) for k, c in (("a", a), ("b", b))}
    empty = {"a": [""] * n["a"], "b": [""] * n["b"]}
    return {k: list(a.get(k, empty["a"] if k == "station_frame" else [np.nan] * n["a"]))
            + list(b.get(k, empty["b"] if k == "station_frame" else [np.nan] * n["b"])) for k in set(a) | set(b)}


@pytest.fixture(scope="module")
def small_case(machine, tmp_path_factory):
    """A geometric identification of a mixed campaign -- 30 commands from 4 table stations and K4-like R-test paths
    around 4 nests (120 distances, 160 nest displacements) -- and the same rows shuffled; the linear axes perfect
    (``--linear perfect``; identified: :func:`test_identified_linear_axes_row_order_does_not_matter`)."""
    truth = no_dropped_truth(synthetic_truth(machine, seed=3))
    cols = mixed(distance_campaign(machine, truth, 30, 4, TABLE_STATIONS, "workpiece"),
                 rtest_campaign(machine, truth, seed=5))
    perm = np.random.default_rng(1).permutation(len(cols["x_cmd_mm"]))
    shuffled = {k: [v[i] for i in perm] for k, v in cols.items()}
    return [identified(tmp_path_factory.mktemp(name), c, "--model", "geometric", "--linear", "perfect")
            for name, c in (("a", cols), ("b", shuffled))]


def test_same_seed_same_result_and_row_order_does_not_matter(small_case, tmp_path):
    (ca, ra), (cb, rb) = small_case
    mc = ("--method", "mc", "--trials", "40", "--seed", "5")
    first, again = (uncertainty(ra, ca, tmp_path / f"{n}.json", *mc) for n in ("first", "again"))
    other = uncertainty(ra, ca, tmp_path / "other.json", "--method", "mc", "--trials", "40", "--seed", "6")
    shuffled = uncertainty(rb, cb, tmp_path / "shuffled.json", *mc)
    assert first["location_errors"] == again["location_errors"]
    assert first["stations_mm"] == again["stations_mm"]
    assert any(first["location_errors"][n] != other["location_errors"][n] for n in free_location(first))
    for n, u in free_location(first).items():
        assert shuffled["location_errors"][n] == pytest.approx(u, rel=1e-9, abs=1e-12), n
    for key in ("nests_mm", "stations_mm", "dead_paths_mm"):  # (labelled by the file's numbers: same order)
        np.testing.assert_allclose(shuffled[key], first[key], rtol=1e-9, atol=1e-15)


def test_identified_linear_axes_row_order_does_not_matter(machine, tmp_path):
    """The same mixed campaign with the linear axes identified (the default): its Monte Carlo u in another row
    order. The smoothness prior's spread was drawn through eigh's eigenvectors, which inside the prior's repeated
    (null) eigenvalues rounding picks: the shuffled campaign's u differed by up to 9 % (E_B0C_urad 6.4 / 5.8, 40
    trials); drawn through the symmetric square root (``psd_sqrt``) they agree to the re-solve's convergence
    (4e-8 relative)."""
    truth = no_dropped_truth(synthetic_truth(machine, seed=3))
    cols = mixed(distance_campaign(machine, truth, 30, 4, TABLE_STATIONS, "workpiece"),
                 rtest_campaign(machine, truth, seed=5))
    perm = np.random.default_rng(1).permutation(len(cols["x_cmd_mm"]))
    shuffled = {k: [v[i] for i in perm] for k, v in cols.items()}
    for n in "ab":
        (tmp_path / n).mkdir()
    (ca, ra), (cb, rb) = (identified(tmp_path / n, c, "--model", "geometric")
                          for n, c in (("a", cols), ("b", shuffled)))
    assert "linear" in json.loads(ra.read_text())
    mc = ("--method", "mc", "--trials", "20", "--seed", "5")
    first, shuffled = (uncertainty(r, c, tmp_path / f"{n}.json", *mc) for n, r, c in (("u1", ra, ca), ("u2", rb, cb)))
    for n, u in free_location(first).items():
        assert shuffled["location_errors"][n] == pytest.approx(u, rel=1e-6), n


def test_a_budget_scales_the_linear_u(small_case, tmp_path):
    """A budget of one reading contributor b: u = b / s of the identification's u (s its reading uncertainty)."""
    campaign, result = small_case[0]
    budget = tmp_path / "budget.yaml"
    budget.write_text("name: one micrometre\nsource: test\ncontributors:\n- {symbol: u1, name: reading, value: 1.0, "
                      "unit: um, k: 1.0, type: B, acts_on: reading}\n")
    own = uncertainty(result, campaign, tmp_path / "own.json", "--method", "linear")
    given = uncertainty(result, campaign, tmp_path / "given.json", "--method", "linear", "--budget", budget)
    s_um = float(own["notes"][-1].split("uncertainty ")[1].split(" um")[0])
    for n, u in free_location(own).items():
        assert given["location_errors"][n] == pytest.approx(u / s_um, rel=2e-3), n
    assert given["budget"] == "one micrometre"


def test_refusals_are_one_line(small_case, tmp_path, capsys):
    (ca, ra), (cb, rb) = small_case
    # another campaign than the result's
    write_five_axis_campaign(tmp_path / "cut.csv", {k: v[:-4] for k, v in _columns(ca).items()})
    code, _, err = olti_in("uncertainty", ra, tmp_path / "cut.csv", "--method", "linear", "--out", tmp_path / "u.json",
                           capsys=capsys)
    error_line(code, err, "not the campaign")
    for figure in ("--map", "--maps"):  # (the robots' figures: a five-axis result's are the report's)
        code, _, err = olti_in("uncertainty", ra, ca, "--method", "linear", figure, tmp_path / "m.png", "--out",
                               tmp_path / "u.json", capsys=capsys)
        error_line(code, err, figure, "olti report")
    assert not (tmp_path / "u.json").exists()


def _columns(path):
    """The columns of a written campaign CSV (name -> list; station_frame as strings, empty cells NaN)."""
    lines = [s for s in path.read_text().splitlines() if s and not s.startswith("#")]
    names = lines[0].split(",")
    rows = [s.split(",") for s in lines[1:]]
    return {c: [r[k] if c == "station_frame" else float(r[k] or "nan") for r in rows] for k, c in enumerate(names)}
