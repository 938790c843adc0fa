"""The cross-machine file comparison of tests/numeric_files.py: what it lets through and what it catches."""

import json

import pytest
from numeric_files import ABS_TOL, REL_TOL, assert_same_numbers, file_differences

HEAD = "# seed 0\nreflector,theta1_deg,displacement_mm,note\n"


def _csv(tmp_path, name, body, head=HEAD):
    p = tmp_path / name
    p.write_text(head + body)
    return p


@pytest.mark.parametrize("a,b", [
    ("0,-140,0.004923975,x\n", "0,-140,0.004923975,x\n"),          # identical
    ("0,-140,0.004923975,x\n", "0,-140,0.004923976,x\n"),          # rounding flip in the last printed digit
    ("0,-140,12.5000000000001,x\n", "0,-140,12.5,x\n"),            # kernel noise far below REL_TOL
    ("0,-140,nan,x\n", "0,-140,nan,x\n"),                          # no reading on both
    ("0,-140,1e-12,x\n", "0,-140,-1e-12,x\n"),                     # around zero: ABS_TOL
])
def test_same_numbers_pass(tmp_path, a, b):
    assert_same_numbers(_csv(tmp_path, "a.csv", a), _csv(tmp_path, "b.csv", b))


@pytest.mark.parametrize("a,b,what", [
    ("1,-140,0.5,x\n", "2,-140,0.5,x\n", "integers differ"),              # reflector index
    ("0,-140,0.5,x\n", "0,-140,0.5,y\n", "text differs"),
    ("0,-140,0.004923975,x\n", "0,-140,0.004923977,x\n", "allowed"),      # two last places: a real change
    ("0,-140,12.500000000,x\n", "0,-140,12.500010000,x\n", "allowed"),  # 10 nm on 12.5 mm
    ("0,-140,nan,x\n", "0,-140,0.1,x\n", "NaN"),
    ("0,-140,0.5,x\n", "0,-140,0.5,x\n0,-120,0.5,x\n", "lines"),          # a row more
    ("0,-140,0.5,x\n", "0,-140,0.5\n", "fields"),
])
def test_different_numbers_fail_naming_line_and_column(tmp_path, a, b, what):
    diffs = file_differences(_csv(tmp_path, "a.csv", a), _csv(tmp_path, "b.csv", b))
    assert diffs and what in "\n".join(diffs)
    if what not in ("lines",):
        assert "a.csv:3" in diffs[0]


def test_comment_and_header_lines_are_exact(tmp_path):
    a = _csv(tmp_path, "a.csv", "0,1,2,x\n")
    assert "a.csv:1" in file_differences(a, _csv(tmp_path, "b.csv", "0,1,2,x\n", HEAD.replace("0", "1", 1)))[0]
    assert "a.csv:2" in file_differences(a, _csv(tmp_path, "c.csv", "0,1,2,x\n", HEAD.replace("note", "n")))[0]


def _json(tmp_path, name, value):
    p = tmp_path / name
    p.write_text(json.dumps(value))
    return p


def test_json_fields():
    base = {"model": "errormap", "n": 3, "L1_mm": 324.97, "P": [[650.0, -450.0]], "u": None}
    near = dict(base, L1_mm=324.97 * (1 + REL_TOL / 10), P=[[650.0 + ABS_TOL / 10, -450.0]])
    from numeric_files import json_differences
    assert json_differences(base, near) == []
    assert json_differences(base, dict(base, n=4)) == ["/n: 3 against 4"]
    assert json_differences(base, dict(base, model="dh"))
    assert "/L1_mm" in json_differences(base, dict(base, L1_mm=324.97001))[0]
    assert "/P[0][1]" in json_differences(base, dict(base, P=[[650.0, -450.001]]))[0]
    assert json_differences(base, dict(base, P=[[650.0, -450.0], [1.0, 2.0]]))
    assert json_differences(base, {k: v for k, v in base.items() if k != "u"})
    assert json_differences({"x": 1}, {"x": True})  # a boolean is not the integer 1
    assert json_differences({"x": 1}, {"x": 1.0 + 1e-12}) == []  # an integer against a float: numerically


def test_json_files(tmp_path):
    a = _json(tmp_path, "a.json", {"x": [1.0, float("nan")]})
    assert file_differences(a, _json(tmp_path, "b.json", {"x": [1.0, float("nan")]})) == []
    diffs = file_differences(a, _json(tmp_path, "c.json", {"x": [1.1, float("nan")]}))
    assert len(diffs) == 1 and diffs[0].startswith(f"{a}: /x[0]")
