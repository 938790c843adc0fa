"""Five-axis identification on the campaigns users bring, not the tool's own (brief, "the data users have"): random
commands within the travel (not planned by the tool), a truth outside the model family
(:func:`olti_drake.model.five_axis_truth.synthetic_truth`: harmonic error motions with backlash), and one
condition each: gross outliers, a single station, fewer readings than unknowns, no direction columns, the
geometric model on a machine with error motions. Each must converge and state a u that covers the error of
its predicted tool points at unseen commands (the result's own u, lack of fit included:
:func:`~olti_drake.estimation.five_axis_uncertainty.tool_point_u`).

Measured when written (seeds 1-3 where named; unseen tool points, RMS error / RMS u, share beyond 3 u):
six stations, clean: 4.0-5.3 / 3.5-7.3 µm, 0.1-0.9 %; with 2 % gross readings (20-200 µm) and loss auto: the
smoothness weight chosen on the l2 fit had seen them as roughness (λ 10 -> 1.6e4; 8.3 / 3.8 µm, 19 % beyond
3 u); chosen again on the robust fit 4.4-6.2 / 4.4-5.3 µm, 0.8-2.3 %. One station riding on the table, 400
commands: refused before (001's four-station rule, for free points); 22 / 73 µm, 0 %. 25 commands from 4
stations (100 readings, 456 unknowns): LM at its 2 000-step cap before (linear convergence); 18 / 21 µm,
1.2 %. Geometric model: 10.4 / 2.5 µm and 45 % beyond 3 u before the residuals' lack of fit was added to the
u; 10.4 / 11.6 µm, 0.4 % after. Units: mm, µrad."""

import numpy as np
import pytest

from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
from olti_drake.estimation.five_axis_uncertainty import tool_point_u
from olti_drake.io.five_axis_io import read_five_axis_campaign, write_five_axis_campaign
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_truth import synthetic_truth

from tests.estimation.test_five_axis_identify import (SIX_TABLE_STATIONS, TABLE_STATIONS, TRUNNION, distance_campaign,
                                                      location_z, no_dropped_truth, random_commands)

SEED = 1


@pytest.fixture(scope="module")
def machine():
    return FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")


@pytest.fixture(scope="module")
def truth(machine):
    return no_dropped_truth(synthetic_truth(machine, seed=SEED))


def identify(machine, cols, folder, name="campaign.csv", **options):
    path = folder / name
    write_five_axis_campaign(path, cols)
    ident = FiveAxisIdentification(read_five_axis_campaign(path, machine), machine, FiveAxisOptions(**options))
    return ident, ident.fit()


def unseen(machine, ident, fit, truth, directions=True):
    """(RMS error mm, RMS u mm, share beyond 3 u) of the predicted tool points at 300 unseen random commands."""
    c, d = random_commands(machine, 300, 77)
    if not directions:
        d = np.ones_like(d)
    p, u = tool_point_u(ident, fit, c, d)
    e = p - truth.truth_positions(c, d)
    return float(np.sqrt(np.mean(e ** 2))), float(np.sqrt(np.mean(u ** 2))), float(np.mean(np.abs(e) > 3 * u))


def covered(ident, fit, truth, share):
    """The free location errors within 3 u of the truth, and the unseen tool points' share beyond 3 u at most
    ``share``."""
    z = location_z(ident, fit, truth)
    assert max(z.values()) < 3.0, {n: round(v, 2) for n, v in z.items() if v >= 3.0}
    assert share <= 0.03, f"{share:.1%} of the unseen tool-point coordinates beyond 3 u"


@pytest.fixture(scope="module")
def clean(machine, truth, tmp_path_factory):
    cols = distance_campaign(machine, truth, 150, SEED, SIX_TABLE_STATIONS, "workpiece")
    ident, fit = identify(machine, cols, tmp_path_factory.mktemp("clean"))
    return cols, ident, fit


def test_gross_outliers_are_down_weighted_and_the_smoothness_chosen_without_them(machine, truth, clean, tmp_path):
    cols, ident0, fit0 = clean
    rng = np.random.default_rng(SEED + 7)
    reading = np.array(cols["displacement_mm"], float)
    bad = rng.choice(reading.size, reading.size // 50, replace=False)
    reading[bad] += rng.choice([-1.0, 1.0], bad.size) * rng.uniform(0.02, 0.2, bad.size)
    ident, fit = identify(machine, dict(cols, displacement_mm=reading), tmp_path, loss="auto")
    assert any("refitted with the Huber loss" in n for n in fit.notes), fit.notes
    rms, u, share = unseen(machine, ident, fit, truth)
    rms0, _, _ = unseen(machine, ident0, fit0, truth)
    assert rms < 1.3 * rms0, (rms, rms0)  # (8.3 / 4.6 µm with the l2 fit's weight kept)
    # The weight is chosen on the robust fit: not the one the outliers made (λ 1.6e4 against 10 clean).
    assert fit.smoothing["weight"] < 0.2 * 1.585e4
    covered(ident, fit, truth, share)
    # The suspect readings are named by their file line (row i of the file written from cols is its line
    # first + i; the campaign is read in canonical order): the worst flagged are corrupted ones, and most corrupted
    # ones are flagged (a few clean readings where the model misfits are flagged beside them).
    lines = set((int(ident.campaign.line.min()) + bad).tolist())
    worst = sorted(fit.outliers, key=lambda o: -abs(o["normalized"]))[:len(lines) // 2]
    assert worst and {o["line"] for o in worst} <= lines, (worst, sorted(lines))
    assert len(lines & {o["line"] for o in fit.outliers}) >= 0.8 * len(lines)
    assert all(o["kind"] == "distance" and "coordinate" not in o for o in fit.outliers)


def test_one_station_on_the_table(machine, truth, clean, tmp_path):
    cols = distance_campaign(machine, truth, 400, SEED, SIX_TABLE_STATIONS[:1], "workpiece")
    ident, fit = identify(machine, cols, tmp_path)
    rms, u, share = unseen(machine, ident, fit, truth)
    _, u_six, _ = unseen(machine, clean[1], clean[2], truth)
    assert u > 3 * u_six  # (one beam direction per command: the u says how little it sees)
    covered(ident, fit, truth, share)
    assert np.all(np.isfinite(fit.std))


@pytest.mark.xfail(strict=True, reason="known gap (issue 25): on thin campaigns the prior-carried maps' u is "
                                       "over-confident: 12 % of the unseen coordinates beyond 3 u on 25 commands (15 % "
                                       "before each map's own roughness joined the u), 2.3 % on 60 (6.9 %), 0.3 % on "
                                       "100; seeds 2 and 3: 0.2-3.3 %; the estimate follows the common weight, "
                                       "which the smooth radial motions of C set 8-12 x too heavy for the angular "
                                       "motions of A, and 100 readings show little of theirs")
def test_fewer_readings_than_unknowns_converges_with_the_prior(machine, truth, tmp_path):
    cols = distance_campaign(machine, truth, 25, SEED, TABLE_STATIONS, "workpiece")
    ident, fit = identify(machine, cols, tmp_path)
    assert len(cols["displacement_mm"]) < len(ident.names)
    rms, u, share = unseen(machine, ident, fit, truth)
    covered(ident, fit, truth, share)


def test_each_maps_own_roughness_joins_the_u_of_a_thin_campaign(machine, truth, tmp_path):
    """60 commands from 4 stations (240 readings, 456 unknowns): the common smoothness weight is the roughness the
    readings show on average, set by C's smooth radial motions; the angular motions of A are rougher (truth 8-12 x
    beyond the common prior). The fit states each map's own weight (one restricted-likelihood step from the
    common one) and puts it in the u, not in the estimate: the unseen tool points beyond 3 u fall from 6.9 % (the
    common weight's u; 7.2 % before each rotary axis' own lever) to 2.3 % (2.9 %), the location errors' worst from
    1.8 to 1.5 u, the estimate unchanged."""
    cols = distance_campaign(machine, truth, 60, SEED, TABLE_STATIONS, "workpiece")
    ident, fit = identify(machine, cols, tmp_path)
    weights, common = fit.smoothing["group_weights"], fit.smoothing["weight"]
    assert set(weights) == {f"E_{c}{L}" for c in "XYZABC" for L in "AC"}
    assert max(weights.values()) <= common and weights["E_CA"] < 0.3 * common, weights
    assert any("each map's own roughness" in n and "E_CA" in n for n in fit.notes), fit.notes
    alone, fit_alone = identify(machine, cols, tmp_path, name="common.csv", smoothing=common)
    assert "group_weights" not in fit_alone.smoothing
    assert np.all(np.abs(fit.x - fit_alone.x) <= 1e-3 * fit_alone.std), "the estimate is the common weight's"
    assert np.all(fit.std >= fit_alone.std * (1 - 1e-9))  # (the maps' own roughness only adds to the u)
    share_alone = unseen(machine, alone, fit_alone, truth)[2]
    rms, u, share = unseen(machine, ident, fit, truth)
    assert share <= 0.5 * share_alone, (share, share_alone)
    assert max(location_z(ident, fit, truth).values()) < 3.0


def test_no_direction_columns(machine, truth, clean, tmp_path):
    cols = {k: v for k, v in clean[0].items() if not k.startswith("dir_")}
    ident, fit = identify(machine, cols, tmp_path)
    assert not ident.errors.bidirectional
    rms, u, share = unseen(machine, ident, fit, truth, directions=False)
    covered(ident, fit, truth, share)


def test_geometric_model_states_its_lack_of_fit(machine, truth, clean, tmp_path):
    ident, fit = identify(machine, clean[0], tmp_path, model="geometric")
    assert fit.lack_of_fit_mm > 0.003 and any(n.startswith("lack of fit") for n in fit.notes), fit.notes
    rms, u, share = unseen(machine, ident, fit, truth)
    assert 0.5 < rms / u < 1.5, (rms, u)  # (not inflated either)
    assert share <= 0.03


def test_an_axis_approached_one_way_keeps_its_motions(machine, truth, tmp_path):
    """K4-like R-test paths (A swept down and back, C turning once, one way): C's reverse branches are tied to
    the forward ones in the gauge, named, instead of C's motions and location errors dropped whole (before: E_ZC,
    E_CC, E_AC, E_BC, E_X0C_mm, E_Y0C_mm held at 0 as 'not separable'; unseen 47 / 60 µm; now 42 / 36 µm)."""
    from tests.estimation.test_five_axis_identify import rtest_campaign

    cols = rtest_campaign(machine, truth, seed=SEED + 5)
    assert np.all(np.asarray(cols["dir_c"]) == 1.0) and len(set(np.asarray(cols["dir_a"]))) == 2
    ident, fit = identify(machine, cols, tmp_path)
    assert ident.errors.one_way == {"C": 1.0}
    assert set(ident.dropped) <= {"E_A0A_urad", "E_C0C_urad"}, ident.dropped
    assert "C approached one way only" in ident.gauge
    motions = ident.layout(fit.x)["error_motions"]
    for c in "XYZABC":
        m = motions[f"E_{c}C"]
        np.testing.assert_allclose(m["reverse"], m["forward"], atol=1e-9)
    c, d = random_commands(machine, 300, 77)
    c[:, 3] = np.random.default_rng(5).uniform(min(cols["a_cmd_deg"]), max(cols["a_cmd_deg"]), len(c))
    p, u = tool_point_u(ident, fit, c, d)
    share = float(np.mean(np.abs(p - truth.truth_positions(c, d)) > 3 * u))
    covered(ident, fit, truth, share)


def one_ball(machine, truth, kind, folder, seed=SEED):
    """(ball mm, identification, fit) of an R-test campaign around one nest (K4-like paths) or one ball (BK-type
    paths, A alone, C alone, A+C), identified as maps every 30 deg."""
    from tests.estimation.test_five_axis_coverage import BALLS, bk_campaign
    from tests.estimation.test_five_axis_identify import rtest_campaign

    if kind == "k4-one-nest":
        ball = np.array([-100.0, 50.0, 280.0])
        cols = rtest_campaign(machine, truth, seed, nests=((tuple(ball), -60.0),))
    else:
        ball = np.asarray(BALLS[0])
        cols = bk_campaign(machine, truth, seed, balls=(tuple(ball),))
    return (ball, cols) + identify(machine, cols, folder, model="errormap", pitch_deg=30.0)


def at_the_ball(machine, ident, fit, truth, cols, ball) -> float:
    """The share of the tool-point coordinates beyond 3 u at the ball for 300 unseen A, C (A within the
    campaign's range, the linear axes putting the nominal tool point on the ball)."""
    from tests.estimation.test_five_axis_identify import _onto

    c, d = random_commands(machine, 300, 77)
    c[:, 3] = np.random.default_rng(5).uniform(min(cols["a_cmd_deg"]), max(cols["a_cmd_deg"]), len(c))
    c[:, :3] = _onto(machine, c, ball)
    inside = np.all((c >= machine.lower) & (c <= machine.upper), axis=1)  # (the linear axes reach the ball)
    assert inside.sum() >= 100, inside.sum()
    p, u = tool_point_u(ident, fit, c[inside], d[inside])
    return float(np.mean(np.abs(p - truth.truth_positions(c[inside], d[inside])) > 3 * u))


@pytest.mark.parametrize("kind", ["k4-one-nest", "bk-one-ball"])
def test_one_nest_or_ball_holds_the_angular_motions_it_cannot_see(machine, truth, kind, tmp_path):
    """An R-test campaign around one nest (K4-like paths) or one ball (BK-type paths): the ball sits at one point
    of the C table at every angle, so C's angular motions trade with its radial and axial ones (t + ω × w at one
    w) -- a trade as smooth as the motions, which the maps' smoothness prior did not break: refused before ('not
    identifiable ... rank deficient by 6' on the K4 nest; 'physically impossible: E_AC 17 265 urad, E_CC 37 958
    urad' on the BK ball). Now E_AC, E_BC, E_CC are held at 0, named with the reason, C's translational motions
    hold the error at the ball, and C's location errors are within 3 u. K4 nest, seeds 1-3: every location error
    within 2.3 u, 0 % of the tool points at the ball beyond 3 u (RMS error 49-71 µm, u 54-83 µm: 40 readings)."""
    ball, cols, ident, fit = one_ball(machine, truth, kind, tmp_path)
    for g in ("E_AC", "E_BC", "E_CC"):
        assert "see axis C move one point only" in ident.dropped.get(g, ""), (g, ident.dropped)
        assert any(n.startswith(f"{g}: not separable") for n in fit.notes)
    assert not {"E_XC", "E_YC", "E_ZC"} & set(ident.dropped)
    z = location_z(ident, fit, truth)
    assert max(v for n, v in z.items() if n[4] == "C") < 3.0, z
    if kind == "k4-one-nest":
        covered(ident, fit, truth, at_the_ball(machine, ident, fit, truth, cols, ball))


def test_one_ball_keeps_the_location_errors_of_a_within_their_u(machine, tmp_path):
    """Seeds 1-3, one BK ball: A's angular motions held (A alone and A+C give two points per A angle) and smoothed
    at the ball's own lever about each axis. Measured: worst location error 1.3 / 1.8 / 1.9 u. With the lever of
    the span of the tool points (nil on one ball: no smoothness prior on the angular maps) E_B0A_urad lay at 11.7 u
    on seed 1 and E_C0A_urad at 3.6 u on seed 3."""
    worst = {}
    for seed in (1, 2, 3):
        t = no_dropped_truth(synthetic_truth(machine, seed=seed))
        (tmp_path / str(seed)).mkdir()
        ball, cols, ident, fit = one_ball(machine, t, "bk-one-ball", tmp_path / str(seed), seed=seed)
        worst[seed] = max(location_z(ident, fit, t).values())
    assert max(worst.values()) < 3.0, worst
