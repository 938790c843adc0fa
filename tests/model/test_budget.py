"""Uncertainty budgets: root-sum-square with the stated k, the shipped tables, one-line errors for bad files.

000 Table 2 (k = 1) and 001 Table 4 (k = 2); combination per JCGM 100 (standard uncertainties
value/k, root-sum-squared per what they act on). Units: µm and rad in the tables, mm and rad out.
"""

import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io.budget import load_budget
from olti_drake.model.budget import Budget, Contributor, paper000_budget, paper001_budget

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.join(ROOT, "data")


def test_rss_uses_each_contributors_k_and_unit():
    b = Budget("t", "test", [
        Contributor("a", "k=2 reading", 2.0, "um", 2.0, "B", "reading"),    # 1 µm standard
        Contributor("b", "k=1 reading", 3.0, "um", 1.0, "B", "reading"),    # 3 µm
        Contributor("c", "nm reading", 4000.0, "nm", 2.0, "A", "reading"),  # 2 µm
        Contributor("d", "pose", 0.004, "mm", 2.0, "A", "pose"),            # 2 µm
        Contributor("e", "beam", 1.0, "mrad", 2.0, "B", "beam_direction"),  # 0.5 mrad
        Contributor("f", "beam", 0.1, "deg", 1.0, "B", "beam_direction"),
    ]).validate()
    assert b.combined("reading") == pytest.approx(1e-3 * np.sqrt(1 + 9 + 4), rel=1e-12)
    assert b.combined("pose") == pytest.approx(2e-3, rel=1e-12)
    assert b.combined("beam_direction") == pytest.approx(np.hypot(0.5e-3, np.radians(0.1)), rel=1e-12)
    # Terms of one kind never leak into another.
    assert Budget("r", "", [Contributor(value=5.0, acts_on="pose")]).combined("reading") == 0.0


def test_paper000_file_matches_table_2():
    b = load_budget(os.path.join(DATA, "budget_paper000.yaml"))
    assert b == paper000_budget()
    assert all(c.k == 1.0 for c in b.contributors)
    um = 1e3
    assert um * b.combined("reading") == pytest.approx(np.sqrt(0.04**2 + 0.19**2 + 0.09**2), rel=1e-12)
    # Table 2 subtotals: u1 = 10 µm (u11..u13 along the beam with u14, the repeatability), u2 = 12 µm.
    pose = {c.symbol: c.standard() for c in b.contributors}
    assert um * np.hypot(b.combined("reading"), pose["u14"]) == pytest.approx(10.0, abs=0.01)
    assert um * np.sqrt(pose["u21"]**2 + pose["u22"]**2 + pose["u23"]**2) == pytest.approx(12.0, abs=0.3)
    assert um * b.combined("pose") == pytest.approx(np.sqrt(10**2 + 5**2 + 5**2 + 10**2), rel=1e-12)
    assert b.combined("beam_direction") == pytest.approx(np.sqrt(2) * 7.17e-4, rel=1e-12)


def test_paper001_file_matches_table_4():
    b = load_budget(os.path.join(DATA, "budget_paper001.yaml"))
    assert b == paper001_budget()  # the shipped file and the simulations' built-in default: one table
    by = {c.symbol: c for c in b.contributors}
    assert sorted(by) == ["u11", "u12", "u13", "u14", "u15", "u16", "u21", "u41", "u42", "u43", "u44"]
    assert all(c.k == 2.0 for c in b.contributors)
    assert [s for s, c in by.items() if c.distribution == "uniform"] == ["u12"]  # the resolution: a quantization
    assert {s for s, c in by.items() if c.type == "B"} == {"u11", "u12", "u13", "u14"}
    um = 1e3
    # k = 2 values halved, then root-sum-squared.
    assert um * b.combined("reading") == pytest.approx(
        np.sqrt(0.02**2 + 0.006**2 + 0.07**2 + 0.12**2 + 0.04**2 + 0.18**2) / 2, rel=1e-12)
    assert um * b.combined("pose") == pytest.approx(2.2 / 2, rel=1e-12)
    assert b.combined("beam_direction") == pytest.approx(
        1e-6 * np.sqrt(2.8**2 + 22.0**2 + 35.2**2 + 60.6**2) / 2, rel=1e-12)
    # Table 4: u4 < 0.01 µm on the reading -- the cosine error D ψ²/2 (std D u_ψ²/√2) even at D = 1 m.
    from olti_drake.model.budget import ReadingErrors
    with_beam = ReadingErrors(b).std([1000.0])[0]
    without = np.hypot(b.combined("reading"), b.combined("pose"))
    assert um * np.sqrt(with_beam**2 - without**2) < 0.01


GOOD = "{symbol: u1, name: test, value: 1.0, unit: um, k: 1.0, type: B, acts_on: reading}"


@pytest.mark.parametrize("entry, words", [
    (GOOD.replace("acts_on: reading", "acts_on: position"), ["acts_on", "position"]),
    (GOOD.replace("acts_on: reading", "acts_on: beam_direction"), ["unit", "um", "beam_direction"]),
    (GOOD.replace("unit: um", "unit: rad"), ["unit", "rad", "reading"]),
    (GOOD.replace("value: 1.0", "value: -0.5"), ["value", "-0.5"]),
    (GOOD.replace("k: 1.0", "k: 0.0"), ["k must be > 0"]),
    (GOOD.replace("k: 1.0", "k: -2.0"), ["k must be > 0"]),
    (GOOD.replace("acts_on: reading", "acts_on: reading, distribution: gaussian"), ["distribution", "gaussian"]),
    (GOOD.replace("acts_on: reading", "acts_on: reading, distrbution: uniform"), ["distrbution"]),
    (GOOD.replace("type: B", "type: C"), ["type", "C"]),
])
def test_bad_budget_is_one_line_error_naming_file_and_field(tmp_path, entry, words):
    path = tmp_path / "bad_budget.yaml"
    path.write_text(f"name: bad\ncontributors:\n- {GOOD.replace('u1', 'u0')}\n- {entry}\n")
    with pytest.raises(InputError) as e:
        load_budget(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg
    for w in words:
        assert w in msg, msg
    if "distrbution" not in words:
        assert "contributors[1] (u1)" in msg, msg  # which entry


def test_typo_in_top_level_key_and_missing_file(tmp_path):
    path = tmp_path / "b.yaml"
    path.write_text("name: x\ncontributers: []\n")
    with pytest.raises(InputError, match="contributers") as e:
        load_budget(path)
    assert str(path) in str(e.value)
    missing = tmp_path / "nope.yaml"
    with pytest.raises(InputError, match="not found") as e:
        load_budget(missing)
    assert str(missing) in str(e.value) and "\n" not in str(e.value)


# -- a budget that cannot be right is refused (issue 11, item 4) ------------------------------------------
def test_budget_without_a_nonzero_contributor_is_refused_where_built_and_where_propagated():
    from olti_drake.model.budget import ReadingErrors

    with pytest.raises(InputError, match="no contributors"):
        Budget("empty").validate()
    zero = Budget("zeros", "", [Contributor("a", "x", 0.0, "um"), Contributor("b", "y", 0.0, "rad", 1.0, "B",
                                                                               "beam_direction")])
    with pytest.raises(InputError, match="budget 'zeros': every contributor is 0"):
        zero.validate()
    # A constructed budget is checked before it is propagated: no uncertainty of 0 (design divided by it).
    for bad in (Budget("empty"), zero):
        with pytest.raises(InputError):
            ReadingErrors(bad)
    ReadingErrors(Budget("one", "", [Contributor("a", "x", 0.0, "um"), Contributor("b", "y", 1.0, "um")]))


@pytest.mark.parametrize("value, unit, k, acts_on, ok", [
    (1000.0, "mm", 1.0, "reading", True),        # 1 m standard uncertainty: the stated bound
    (1000.1, "mm", 1.0, "reading", False),
    (1.5, "m", 2.0, "pose", True),               # value / k = 0.75 m
    (1.5, "m", 1.0, "pose", False),
    (1e300, "um", 1.0, "reading", False),        # used to overflow in the root-sum-square
    (10.0, "deg", 1.0, "beam_direction", True),  # 10 deg: the stated bound
    (10.5, "deg", 1.0, "beam_direction", False),
    (0.2, "rad", 1.0, "beam_direction", False),  # 11.5 deg
    (1.0, "um", 11.0, "reading", False),         # coverage factor beyond 10
    (float("inf"), "um", 1.0, "reading", False),
    (float("nan"), "um", 1.0, "reading", False),
])
def test_contributor_values_within_physical_bounds(value, unit, k, acts_on, ok):
    from olti_drake.model.budget import MAX_ANGLE_RAD, MAX_LENGTH_MM

    assert (MAX_LENGTH_MM, MAX_ANGLE_RAD) == (1000.0, pytest.approx(np.radians(10)))
    b = Budget("t", "", [Contributor("u1", "base", 1.0, "um"), Contributor("u9", "tested", value, unit, k, "B",
                                                                           acts_on)])
    if ok:
        assert b.validate() is b and np.isfinite(b.combined(acts_on))
    else:
        with pytest.raises(InputError) as e:
            b.validate("b.yaml")
        assert str(e.value).startswith("b.yaml: contributors[1] (u9): ") and "\n" not in str(e.value)
