"""Tests of olti_drake.model.plan: the paper's bidirectional plan (000 §4.1, Eq. (11)-(12)) and file I/O."""

from pathlib import Path

import numpy as np
import pytest

from olti_drake.io.plan_io import load_plan, save_plan
from olti_drake.model.plan import BidirectionalGrid, Plan, bidirectional_grid

DATA = Path(__file__).resolve().parents[2] / "data" / "plan_paper000.csv"

EQ11 = [0, 20, 40, 60, 80, 100, 120, 140, 140, 120, 100, 80, 60, 40, 20, 0]
EQ12 = list(range(-140, 61, 20)) + list(range(60, -141, -20))


def expected_poses(theta1, theta2):
    """Measured poses in order with the sweep's direction of travel, built from the value lists."""
    def dirs(vals):
        half = len(vals) // 2
        out = np.sign(vals[half - 1] - vals[0]) or 1.0
        return [out] * half + [-out] * half
    rows = [(a, b, d1, d2) for a, d1 in zip(theta1, dirs(theta1))
            for b, d2 in zip(theta2, dirs(theta2))]
    return np.array(rows, dtype=float)


def check_directions(plan, theta1, theta2):
    m = plan.measured()
    exp = expected_poses(theta1, theta2)
    got = np.column_stack([m.theta1_deg, m.theta2_deg, m.dir1, m.dir2])
    np.testing.assert_array_equal(got, exp)


# --- the paper's plan ------------------------------------------------------

def test_paper_plan_counts_and_sequences():
    plan = BidirectionalGrid().plan()
    m = plan.measured()
    assert plan.n_measured == 352 == len(m.index)
    assert len(EQ11) == 16 and len(EQ12) == 22
    np.testing.assert_array_equal(m.theta2_deg[:16], EQ11)
    assert np.all(m.theta1_deg[:16] == -140)
    # θ1 stays constant over each 16-pose θ2 sweep and follows Eq. (12).
    t1 = m.theta1_deg.reshape(22, 16)
    assert np.all(t1 == t1[:, :1])
    np.testing.assert_array_equal(t1[:, 0], EQ12)
    np.testing.assert_array_equal(m.theta2_deg.reshape(22, 16), np.tile(EQ11, (22, 1)))


def test_paper_plan_directions_self_check():
    """Every measured row, turnarounds included, is approached from its sweep's direction."""
    plan = bidirectional_grid()
    check_directions(plan, EQ12, EQ11)
    m = plan.measured()
    d = np.column_stack([m.dir1, m.dir2]).reshape(22, 16, 2)
    assert np.all(d[0, 0] == [1, 1])      # first -140, first 0: from below
    assert d[0, 8, 1] == -1               # second 140: from above
    assert np.all(d[1:, 0, 1] == 1)       # first 0 of every θ2 sweep: from below
    assert d[11, 0, 0] == -1              # second 60: from above
    assert d[10, 15, 0] == 1              # last pose at the first 60 is still +1


def test_paper_plan_overrun_rows():
    plan = bidirectional_grid(overrun_deg=2.0)
    extra = ~plan.measure
    # start + one θ2 turnaround per θ1 value + one θ2 restart per later θ1 value
    assert len(plan) == 352 + 1 + 22 + 21
    assert extra[0] and plan.measure[1]
    np.testing.assert_array_equal([plan.theta1_deg[0], plan.theta2_deg[0]], [-142, -2])
    # Overrun rows are unmeasured and lie outside the measured grid by exactly 2 deg.
    t1, t2 = plan.theta1_deg[extra], plan.theta2_deg[extra]
    outside = (t1 < -140) | (t1 > 60) | (t2 < 0) | (t2 > 140)
    assert np.all(outside)
    assert set(np.round(t2, 9)) <= {-2.0, 142.0, 0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 140.0}
    assert set(np.round(t1[(t1 < -140) | (t1 > 60)], 9)) == {-142.0, 62.0}
    # Every row is a real move (no row repeats the previous command).
    assert not np.any(np.all(np.diff(np.column_stack([plan.theta1_deg, plan.theta2_deg]),
                                     axis=0) == 0, axis=1))


# --- variants --------------------------------------------------------------

def test_negative_elbow_directions():
    plan = bidirectional_grid(-140, 60, 20, 0, -140, 20)
    theta2 = [0, -20, -40, -60, -80, -100, -120, -140, -140, -120, -100, -80, -60, -40, -20, 0]
    check_directions(plan, EQ12, theta2)
    assert plan.measured().dir2[0] == -1  # first 0 approached from above: the out direction is -1
    assert plan.theta2_deg[0] == 2.0


def test_descending_directions():
    plan = bidirectional_grid(60, -140, 20, 140, 0, 20, overrun_deg=1.5)
    theta1 = EQ12[11:] + EQ12[:11]  # 60 .. -140, -140 .. 60
    theta2 = [140, 120, 100, 80, 60, 40, 20, 0, 0, 20, 40, 60, 80, 100, 120, 140]
    check_directions(plan, theta1, theta2)
    assert (plan.theta1_deg[0], plan.theta2_deg[0]) == (61.5, 141.5)


def test_fractional_step():
    plan = bidirectional_grid(0, 1, 0.1, 0, 0.5, 0.25)
    vals = [0.1 * i for i in range(10)] + [1.0]
    check_directions(plan, vals + vals[::-1], [0, 0.25, 0.5, 0.5, 0.25, 0])


def test_single_point_sweep_measures_both_directions():
    plan = bidirectional_grid(0, 0, 10, 0, 20, 10)
    check_directions(plan, [0, 0], [0, 10, 20, 20, 10, 0])


@pytest.mark.parametrize("kwargs, word", [
    (dict(theta1_step=0), "theta1_step"),
    (dict(theta2_step=-20), "theta2_step"),
    (dict(theta1_step=30), "theta1_step"),
    (dict(theta2_stop=130.5), "theta2_step"),
    (dict(overrun_deg=0), "overrun_deg"),
    (dict(theta1_start=float("nan")), "theta1_start"),
])
def test_generator_validation(kwargs, word):
    with pytest.raises(ValueError, match=word) as exc:
        bidirectional_grid(**kwargs)
    assert "\n" not in str(exc.value)


def test_plan_validation():
    with pytest.raises(ValueError, match="rows"):
        Plan([0, 1], [0], [1, 1])
    with pytest.raises(ValueError, match="theta2_deg"):
        Plan([0, 1], [0, np.inf], [1, 1])
    with pytest.raises(ValueError, match="no measured row"):
        Plan([0, 1], [0, 1], [0, 0])
    with pytest.raises(ValueError, match="measure"):
        Plan([0, 1], [0, 1], [1, 2])
    p = Plan([0, 1], [0, 1], [0, 1])
    assert p.measure.dtype == bool and len(p) == 2 and p.n_measured == 1
    np.testing.assert_array_equal(Plan([0, 5, 5, 3], [0, 0, -1, -1], [1, 1, 1, 1]).directions(),
                                  [[1, 1], [1, 1], [1, -1], [-1, -1]])


# --- files -----------------------------------------------------------------

def test_shipped_file_matches_generator():
    shipped, gen = load_plan(DATA), BidirectionalGrid().plan()
    for key in ("theta1_deg", "theta2_deg", "measure"):
        np.testing.assert_array_equal(getattr(shipped, key), getattr(gen, key))
    assert DATA.read_text().startswith("#")


def test_round_trip_exact(tmp_path):
    t1 = np.array([-140.0, 0.1, 1 / 3, -0.0, 1e-17, 123.456789012345678])  # within the +-720 deg physical bound
    plan = Plan(t1, t1[::-1] * np.pi, [0, 1, 1, 0, 1, 1])
    f = tmp_path / "p.csv"
    save_plan(plan, f)
    back = load_plan(f)
    np.testing.assert_array_equal(back.theta1_deg, plan.theta1_deg)
    np.testing.assert_array_equal(back.theta2_deg, plan.theta2_deg)
    np.testing.assert_array_equal(back.measure, plan.measure)
    lines = f.read_text().splitlines()
    assert lines[0].startswith("#") and lines[1] == "theta1_deg,theta2_deg,measure"
    assert lines[2].startswith("-140,") and lines[2].endswith(",0")  # integers print as integers


def test_column_order_comments_extra_and_default_measure(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("# a plan\nnote,measure,theta2_deg,theta1_deg\n# mid comment\n\n"
                 "a,0,5,-1\nb,1,6,-2\n")
    p = load_plan(f)
    np.testing.assert_array_equal(p.theta1_deg, [-1, -2])
    np.testing.assert_array_equal(p.theta2_deg, [5, 6])
    np.testing.assert_array_equal(p.measure, [False, True])
    f.write_text("theta2_deg,theta1_deg\n1,2\n3,4\n")
    p = load_plan(f)
    assert p.measure.all() and p.n_measured == 2
    np.testing.assert_array_equal(p.theta1_deg, [2, 4])


@pytest.mark.parametrize("text, parts", [
    ("# c\ntheta1_deg,measure\n1,1\n", [":2:", "theta2_deg"]),
    ("theta1_deg,theta2_deg,measure\n1,2,1\n1,x,1\n", [":3:", "theta2_deg", "'x'"]),
    ("theta1_deg,theta2_deg,measure\n# c\n1,2,1\nnan,2,1\n", [":4:", "theta1_deg"]),
    ("theta1_deg,theta2_deg,measure\n1,2,2\n", [":2:", "measure"]),
    ("theta1_deg,theta2_deg,measure\n1,2\n", [":2:", "fields"]),
    ("theta1_deg,theta2_deg,theta1_deg\n1,2,3\n", [":1:", "duplicate", "theta1_deg"]),
    ("# only a comment\ntheta1_deg,theta2_deg\n", ["empty"]),
    ("", ["empty"]),
    ("theta1_deg,theta2_deg,measure\n1,2,0\n", ["no measured row"]),
])
def test_load_errors_name_file_line_column(tmp_path, text, parts):
    f = tmp_path / "bad_plan.csv"
    f.write_text(text)
    with pytest.raises(ValueError) as exc:
        load_plan(f)
    msg = str(exc.value)
    assert "\n" not in msg and "bad_plan.csv" in msg
    for part in parts:
        assert part in msg


def test_yaml_plan(tmp_path):
    f = tmp_path / "grid.yaml"
    f.write_text("theta1_start: -20\ntheta1_stop: 20\ntheta2_start: 0\ntheta2_stop: -40\n")
    p = load_plan(f)
    check_directions(p, [-20, 0, 20, 20, 0, -20], [0, -20, -40, -40, -20, 0])
    assert load_plan(_write(tmp_path / "d.yml", "{}\n")).n_measured == 352
    for name, text in (("typo.yaml", "theta1_strat: 3\n"), ("step.yaml", "theta2_step: 0\n"),
                       ("type.yaml", "overrun_deg: [1, 2]\n")):
        with pytest.raises(ValueError) as exc:
            load_plan(_write(tmp_path / name, text))
        assert name in str(exc.value) and "\n" not in str(exc.value)


def _write(path, text):
    path.write_text(text)
    return path


def test_shipped_yaml_plan_expands_to_the_shipped_csv():
    data = Path(__file__).resolve().parents[2] / "data"
    a, b = load_plan(data / "plan_paper000.yaml"), load_plan(data / "plan_paper000.csv")
    np.testing.assert_array_equal(a.theta1_deg, b.theta1_deg)
    np.testing.assert_array_equal(a.theta2_deg, b.theta2_deg)
    np.testing.assert_array_equal(a.measure, b.measure)
