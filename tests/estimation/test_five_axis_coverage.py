"""The stated u of a five-axis identification covers its error (issue 25 "must show"): truths outside the model
family (:func:`olti_drake.model.five_axis_truth.synthetic_truth`: harmonic error motions with backlash, location
errors of 10-50 µm / 20-100 µrad) identified as maps every 30 deg (smoothing 'auto') on a distance campaign (random
commands, stations riding on the table) and on an R-test campaign (ISO 10791-6 BK-type paths around three balls:
each rotary axis alone, then both), neither planned by the tool's design.

Rules (the map representation: :meth:`~olti_drake.estimation.five_axis.FiveAxisIdentification.representation` in
the u, :func:`~olti_drake.model.five_axis_errors.representation_bound` b in the comparison):

* every free location error within 3 u of the truth;
* the free error-motion values (both branches, every node) within 3 u + b for >= 99 % of them, b the grid's
  representation bound of that motion branch (the truth sampled at the nodes and interpolated as the model does:
  its largest deviation from the truth over the travel);
* the u not absurdly inflated: the median |error| / u of the map values and of the location errors >= 0.2 (for
  a normal error it is 0.67).

Measured (``benchmarks/coverage_five_axis.py``) before the representation was in the u, on 3 seeds x 15/30 deg:
location errors up to 4.7 u, map values beyond 3 u + b up to 4 %, unseen tool points up to 8.6 u (18 % beyond 3 u).
"""

import numpy as np
import pytest

from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
from olti_drake.estimation.five_axis_uncertainty import tool_point_u
from olti_drake.io.five_axis_io import read_five_axis_campaign, write_five_axis_campaign
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_errors import COMPONENTS, representation_bound
from olti_drake.model.five_axis_plan import bk_paths, combine
from olti_drake.model.five_axis_truth import synthetic_truth
from tests.estimation.test_five_axis_identify import (NOISE_MM, SIX_TABLE_STATIONS, TRUNNION, command_columns,
                                                      distance_campaign, no_dropped_truth, random_commands,
                                                      rtest_campaign)

#: The balls of the R-test campaign (workpiece frame, mm).
BALLS = ((100.0, 0.0, 150.0), (-80.0, 80.0, 200.0), (0.0, -60.0, 220.0))


@pytest.fixture(scope="module")
def machine():
    return FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")


def bk_campaign(machine, truth, seed, balls=BALLS, steps=24):
    """R-test columns: ISO 10791-6 BK-type paths (:func:`~olti_drake.model.five_axis_plan.bk_paths`: A alone, C
    alone, A+C, forth and back; A over -30..30 deg, where the linear axes reach the balls of
    ``diagrams/machine_5axis.yaml``) around every ball, each path its own nest; the ball's displacement from the
    nest's zero (an arbitrary set-up offset) read with 1 µm noise."""
    rng = np.random.default_rng(seed)
    plans = [bk_paths(machine, b, steps, ranges_deg={"A": (-30.0, 30.0)}) for b in balls]
    for k, p in enumerate(plans):
        p.nest = p.nest + k * len(p.path_names)
    plan = combine(*plans)
    centres = np.vstack([p.nests_mm for p in plans])[plan.nest]
    d = plan.rotary_directions(machine)
    offsets = rng.uniform(-0.05, 0.05, (plan.nest.max() + 1, 3))[plan.nest]
    disp = truth.truth_positions(plan.commands, d) - centres - offsets + rng.normal(0, NOISE_MM, centres.shape)
    cols = command_columns(machine, plan.commands, d)
    cols.update(nest=plan.nest, dx_mm=disp[:, 0], dy_mm=disp[:, 1], dz_mm=disp[:, 2])
    return cols


def campaign_columns(machine, truth, kind, seed):
    if kind == "distance":
        return distance_campaign(machine, truth, 150, seed, SIX_TABLE_STATIONS, "workpiece")
    if kind == "k4":  # ISO 10791-6 K4-like paths: A swept down and back while C turns once, 4 nests
        return rtest_campaign(machine, truth, seed)
    return bk_campaign(machine, truth, seed)


def identified(machine, kind, seed, folder, pitch_deg=30.0):
    """(identification, fit, truth): the truth of ``seed`` (its location errors the campaign cannot separate at
    0: a relative measurement does not see them, docs/five_axis.md) read by a ``kind`` campaign and identified."""
    truth = no_dropped_truth(synthetic_truth(machine, seed=seed))
    for attempt in range(2):
        path = folder / f"{kind}-{seed}-{attempt}.csv"
        write_five_axis_campaign(path, campaign_columns(machine, truth, kind, seed))
        ident = FiveAxisIdentification(read_five_axis_campaign(path, machine), machine,
                                       FiveAxisOptions(model="errormap", pitch_deg=pitch_deg))
        dropped = [n for n in ident.dropped if truth.location.get(n, 0.0) != 0.0]
        if not dropped:
            return ident, ident.fit(), truth
        truth = no_dropped_truth(truth, tuple(dropped) + ("E_A0A_urad", "E_C0C_urad"))
    raise AssertionError(f"{kind}: the dropped groups changed with the truth")


def coverage(ident, fit, truth) -> dict:
    """{location: {name: |error| / u}, map_z: |error| / u of every free map value, map_beyond: whether each is
    beyond 3 u + b} (module docstring)."""
    lay, unc = ident.layout(fit.x), ident.layout(fit.std)
    location = {n: abs(v - truth.location.get(n, 0.0)) / unc["location_errors"][n]
                for n, v in lay["location_errors"].items() if n not in ident.dropped}
    bound = representation_bound(ident.errors, truth)
    z, beyond = [], []
    for name, m in lay["error_motions"].items():
        if name in ident.position_model.held:
            continue
        for branch, sign in (("forward", 1.0), ("reverse", -1.0)):
            true = truth.motion_values(m["axis"], np.asarray(m["grid_deg"]), sign)[:, COMPONENTS.index(name[2])]
            err, u = np.abs(np.asarray(m[branch]) - true), np.asarray(unc["error_motions"][name][branch])
            z.append(err / u)
            beyond.append(err > 3 * u + bound[(name, branch)])
    return {"location": location, "map_z": np.concatenate(z), "map_beyond": np.concatenate(beyond)}


# (one R-test seed: its fit takes ~1 000 LM steps over the smoothing's rounds, ~20 s; the benchmark runs three)
@pytest.fixture(scope="module", params=[("distance", 1), ("distance", 2), ("rtest", 1)],
                ids=lambda p: f"{p[0]}-{p[1]}")
def case(request, machine, tmp_path_factory):
    kind, seed = request.param
    ident, fit, truth = identified(machine, kind, seed, tmp_path_factory.mktemp(kind))
    return ident, fit, truth, coverage(ident, fit, truth)


def test_location_errors_within_3u(case):
    ident, _, _, cov = case
    assert len(cov["location"]) >= 6 and max(cov["location"].values()) < 3.0, (cov["location"], ident.dropped)


def test_error_motions_within_3u_plus_the_representation_bound(case):
    beyond = case[3]["map_beyond"]
    assert beyond.size >= 100 and np.mean(beyond) <= 0.01, np.mean(beyond)


def test_the_u_is_not_inflated(case):
    cov = case[3]
    assert np.median(cov["map_z"]) >= 0.2, np.median(cov["map_z"])
    assert np.median(list(cov["location"].values())) >= 0.2, cov["location"]


def test_the_representation_is_stated(case):
    """The fit says the component (its note) and the result carries its lack of fit for predictions."""
    ident, fit, _, _ = case
    assert any(n.startswith("map representation") for n in fit.notes), fit.notes
    assert fit.lack_of_fit_mm > 0.0
    C, lack = ident.representation(fit.x)
    assert lack == pytest.approx(fit.lack_of_fit_mm, rel=1e-9) and np.all(np.diag(C) >= 0)


def test_unseen_tool_points_within_their_u(machine, case):
    """Predicted tool points at 200 unseen commands (workpiece frame): |error| within 3 u for >= 97 % of the
    coordinates, median |error| / u >= 0.2 (covariance and the lack of fit, :func:`tool_point_u`)."""
    ident, fit, truth, _ = case
    c, d = random_commands(machine, 200, 77)
    p, u = tool_point_u(ident, fit, c, d)
    z = np.abs(p - truth.truth_positions(c, d)) / u
    assert np.mean(z > 3.0) <= 0.03 and np.median(z) >= 0.2, (np.mean(z > 3.0), np.median(z))


def test_k4_paths_converge_and_cover_the_truth(machine, tmp_path):
    """ISO 10791-6 K4-like R-test paths on the 30° grid: LM crawled there until its cap (refused as not
    converged) before steps repeated in one direction were lengthened (calibration._extrapolate); now the fit
    converges, the location errors and error motions are within their u, and that u is not inflated: median
    |error| / u of the location errors was 0.14 while C (turned one way) was left free in both branches, 0.29-1.17
    since its reverse branches are tied to the forward ones (FiveAxisErrors one_way)."""
    ident, fit, truth = identified(machine, "k4", 2, tmp_path)
    cov = coverage(ident, fit, truth)
    assert len(cov["location"]) >= 6 and max(cov["location"].values()) < 3.0, cov["location"]
    assert cov["map_beyond"].size >= 100 and np.mean(cov["map_beyond"]) <= 0.01
    assert np.median(list(cov["location"].values())) >= 0.2, cov["location"]
    assert np.median(cov["map_z"]) >= 0.2, np.median(cov["map_z"])
