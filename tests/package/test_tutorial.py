"""docs/tutorial.md runs as written: every ```bash block, in order, in one scratch directory.

The convention (also stated in an HTML comment at the top of the tutorial):

- ```bash            run, in order, with ``set -euo pipefail``; must exit 0;
- ```bash-needs-dot  run like ```bash when Graphviz ``dot`` is installed, skipped otherwise;
- ```bash-norun      never run (installation, real hardware, interactive sessions);
- ```output          what the preceding ```bash block prints, checked against what it printed: the
                     quoted lines in order, consecutive unless a line ``...`` stands between them;
                     ``...`` (or ``[...]``) inside a line stands for any text; numbers within one unit
                     of their last quoted digit (integers exactly); a number written ``~N`` varies from
                     run to run or CPU to CPU (durations, counts at an interruption, solver
                     iterations: the BLAS kernels move a stopping test) and is not compared;
- anything else (```text, ```yaml, ...) is an illustration or a file excerpt, not checked.

The scratch directory holds symlinks to the repository's ``diagrams/``, ``data/`` and
``examples/``, so the commands read exactly the paths a reader types at the repository root
and everything they write lands in the scratch ``work/``; the repository is checked unchanged.
After the blocks, the main outputs and the numbers the tutorial quotes are checked.
"""

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from decimal import Decimal
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TUTORIAL = ROOT / "docs" / "tutorial.md"
LINKED = ("diagrams", "data", "examples")
RUN, NEEDS_DOT, NORUN, OUTPUT = "bash", "bash-needs-dot", "bash-norun", "output"
FENCE = re.compile(r"^```([^\s`]*)\s*$")


def code_blocks(text):
    """[(info, code, first line number)] of the fenced blocks of a Markdown text."""
    blocks, info, start, lines = [], None, 0, []
    for n, line in enumerate(text.splitlines(), 1):
        m = FENCE.match(line)
        if info is None:
            if m:
                info, start, lines = m.group(1), n, []
        elif line.rstrip() == "```":
            blocks.append((info, "\n".join(lines) + "\n", start))
            info = None
        else:
            lines.append(line)
    assert info is None, f"docs/tutorial.md: the block opened at line {start} is never closed"
    return blocks


ALL_BLOCKS = code_blocks(TUTORIAL.read_text(encoding="utf-8"))
BLOCKS = [b for b in ALL_BLOCKS if b[0] in (RUN, NEEDS_DOT)]


def quoted_outputs():
    """[(quoted text, its line, line of the run block it quotes)]: each ```output block and the block before."""
    out, last = [], None
    for info, code, line in ALL_BLOCKS:
        if info in (RUN, NEEDS_DOT):
            last = line
        elif info == OUTPUT:
            assert last is not None, f"docs/tutorial.md line {line}: an output block before any run block"
            out.append((code, line, last))
    return out


QUOTED = quoted_outputs()
_NUMBER = re.compile(r"(~?)([-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?)")
_ELLIPSIS = re.compile(r"\[\.\.\.\]|\.\.\.")


def _quoted_line(quoted):
    """(regex matching a printed line, [(varies, quoted number text)]) of one quoted line."""
    regex, numbers = [], []
    parts = _ELLIPSIS.split(quoted)
    for k, part in enumerate(parts):
        # "readings ..." also matches "readings" at the end of the line: blanks next to "..." are elided with it.
        part = part.lstrip() if k > 0 else part
        part = part.rstrip() if k < len(parts) - 1 else part
        pos, pieces = 0, []
        for m in _NUMBER.finditer(part):
            pieces += [re.escape(part[pos:m.start()]), r"([-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?)"]
            numbers.append((m.group(1) == "~", m.group(2)))
            pos = m.end()
        regex.append("".join(pieces) + re.escape(part[pos:]))
    return re.compile(".*?".join(regex)), numbers


def _number_problem(quoted, printed):
    """None if ``printed`` is ``quoted`` within one unit of its last quoted digit (integers exactly)."""
    if quoted.lstrip("+-").isdigit():
        ok = printed.lstrip("+-").isdigit() and int(quoted) == int(printed)
    else:
        unit = 10.0 ** Decimal(quoted).as_tuple().exponent
        ok = abs(float(printed) - float(quoted)) <= 1.000001 * unit
    return None if ok else f"{printed} (quoted {quoted})"


def quoted_output_problems(quoted_text, printed_text):
    """Where the quoted output is not what was printed (the rules of the module docstring); [] if it is."""
    printed = [line.rstrip() for line in printed_text.splitlines()]
    problems, i, free = [], 0, True
    for q in quoted_text.splitlines():
        if not q.strip():
            continue
        if _ELLIPSIS.fullmatch(q.strip()):
            free = True
            continue
        regex, numbers = _quoted_line(q.rstrip())
        candidates = range(i, len(printed)) if free else range(i, min(i + 1, len(printed)))
        j = next((j for j in candidates if regex.fullmatch(printed[j])), None)
        if j is None:
            near = printed[i] if i < len(printed) else "(end of output)"
            problems.append(f"quoted {q.strip()!r} is not printed" + ("" if free else f"; printed {near!r}"))
            free = True  # resynchronize on the next quoted line
            continue
        values = regex.fullmatch(printed[j]).groups()
        bad = [p for (varies, qn), pn in zip(numbers, values) if not varies for p in [_number_problem(qn, pn)] if p]
        if bad:
            problems.append(f"quoted {q.strip()!r}, printed {printed[j]!r}: {', '.join(bad)}")
        i, free = j + 1, False
    return problems


def snapshot():
    """Names, sizes and mtimes of every file under the linked repository folders."""
    out = {}
    for name in LINKED:
        for p in (ROOT / name).rglob("*"):
            if p.is_file() and "__pycache__" not in p.parts:
                st = p.stat()
                out[str(p.relative_to(ROOT))] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """The reader's working directory: symlinks to diagrams/, data/, examples/; nothing else."""
    d = tmp_path_factory.mktemp("tutorial")
    for name in LINKED:
        (d / name).symlink_to(ROOT / name, target_is_directory=True)
    env = dict(os.environ, MPLBACKEND="Agg")
    # `olti` and `python` of this interpreter's environment first on PATH.
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    state = {"dir": d, "env": env, "failed": None, "out": {}}
    before = snapshot()
    yield state
    assert snapshot() == before, "the tutorial's commands changed files in the repository"


def test_tutorial_conventions():
    text = TUTORIAL.read_text(encoding="utf-8")
    head = text.split("-->")[0]
    assert text.startswith("<!--") and "bash-norun" in head and "```output" in head, \
        "the fence convention must be stated in the HTML comment at the top"
    assert len(QUOTED) >= 6, "the commands' output is quoted in ```output blocks (checked), not ```text"
    blocks = code_blocks(text)
    infos = {info for info, _, _ in blocks}
    unknown = {i for i in infos if i.startswith("bash")} - {RUN, NEEDS_DOT, NORUN}
    assert not unknown, f"unknown bash fence info strings {unknown}"
    assert sum(info == RUN for info, _, _ in blocks) >= 8
    norun = "".join(code for info, code, _ in blocks if info == NORUN)
    assert "pip install -e ." in norun and "--meshcat" in norun and "olti run my_robot.yaml" in norun
    for info, code, line in blocks:
        if info in (RUN, NEEDS_DOT):
            assert "pip install" not in code, f"line {line}: installation must not run in the test"
            for m in re.finditer(r"--out\s+(\S+)|(?<![-=>])>>?\s*([^\s;|&)]+)", code):
                target = m.group(1) or m.group(2)
                assert target.startswith("work/") or target.startswith("/dev/null"), \
                    f"line {line}: writes {target} outside work/"


@pytest.mark.parametrize("info,code,line", BLOCKS, ids=[f"line{b[2]}" for b in BLOCKS])
def test_block(scratch, info, code, line):
    if scratch["failed"] is not None:
        pytest.skip(f"an earlier block failed (line {scratch['failed']})")
    if info == NEEDS_DOT and shutil.which("dot") is None:
        pytest.skip("Graphviz `dot` is not installed (apt-get install graphviz)")
    try:
        proc = subprocess.run(["bash", "-c", "set -euo pipefail\n" + code], cwd=scratch["dir"],
                              env=scratch["env"], capture_output=True, text=True, timeout=180)
    except subprocess.TimeoutExpired:
        scratch["failed"] = line
        raise
    scratch["out"][line] = proc.stdout + proc.stderr
    if proc.returncode != 0:
        scratch["failed"] = line
    assert proc.returncode == 0, (f"docs/tutorial.md block at line {line} exited {proc.returncode}\n"
                                  f"--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}")


def test_quoted_output_rules():
    printed = "model dh: 1055 readings\n  L1 = 324.9918 +- 0.0036 mm\nwrote a\n  residual RMS 51.53 um, 2 it, 0.68 s\n"
    assert quoted_output_problems("model dh: 1055 readings\n  L1 = 324.9919 +- 0.0036 mm\n...\n"
                                  "  residual RMS 51.53 um, ~2 it, ~0.1 s\n", printed) == []
    assert quoted_output_problems("  L1 = 324.99... mm\n", printed) == []
    assert quoted_output_problems("max residual ~8e-14 mm\n", "max residual 3e-15 mm\n") == []
    assert quoted_output_problems("max residual 8e-14 mm\n", "max residual 9e-14 mm\n") == []
    assert quoted_output_problems("max residual 8e-14 mm\n", "max residual 3e-15 mm\n")
    assert quoted_output_problems("model dh: 1055 readings ...\n", printed) == []
    assert quoted_output_problems("  L1 = 324.9921 +- 0.0036 mm\n", printed)       # two units off
    assert quoted_output_problems("model dh: 1056 readings\n", printed)             # an integer
    assert quoted_output_problems("model errormap: 1055 readings\n", printed)       # the text
    assert quoted_output_problems("model dh: 1055 readings\n  residual RMS 51.53 um, 2 it, ~1 s\n", printed)
    assert quoted_output_problems("  residual RMS 51.53 um, 2 it, ~1 s\nmodel dh: 1055 readings\n", printed)


@pytest.mark.parametrize("quoted,line,run_line", QUOTED, ids=[f"line{q[1]}" for q in QUOTED])
def test_quoted_output_is_what_the_commands_print(scratch, quoted, line, run_line):
    """Every ```output block is what the block before it printed (numbers within their last digit)."""
    if scratch["failed"] is not None:
        pytest.skip(f"a block failed (line {scratch['failed']})")
    if run_line not in scratch["out"]:
        pytest.skip(f"the block at line {run_line} did not run")
    problems = quoted_output_problems(quoted, scratch["out"][run_line])
    assert not problems, (f"docs/tutorial.md line {line} quotes output the block at line {run_line} did not print; "
                          "update the tutorial:\n" + "\n".join(problems)
                          + "\n--- printed\n" + scratch["out"][run_line])


def quoted_problem(value, quoted, what, about=False):
    """None if ``value`` is the number the tutorial's prose quotes, within one unit of its last digit.

    Prose rounds measured values, integers too ("24 µm"): here an integer is not a count. ``about``:
    the prose says "about N" of a number that varies from run to run; within 15 % of N (the emulated
    run's residual RMS was seen between 15.1 and 15.4 µm over runs interrupted at different readings).
    """
    if about:
        ok = abs(float(value) - float(quoted)) <= 0.15 * abs(float(quoted))
        return None if ok else f"docs/tutorial.md says {what} = about {quoted}; the run gives {value:.6g}"
    problem = _number_problem(quoted if "." in quoted else quoted + ".", repr(float(value)))
    return None if problem is None else f"docs/tutorial.md says {what} = {quoted}; the run gives {value:.6g}"


def _validation_table(report_html):
    """{(command set, model): (RMS, max, fitted rotation)} from the report's validation table (µm, mdeg)."""
    text = Path(report_html).read_text(encoding="utf-8")
    out = {}
    for row in re.findall(r"<tr>(.*?)</tr>", text):
        cells = [re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
        if len(cells) == 7 and cells[1] in ("error map", "D-H"):
            out[cells[0], cells[1]] = tuple(float(c) for c in cells[3:6])
    assert out, f"{report_html}: no validation table"
    return out


def _block_output(scratch, needle):
    for info, code, line in BLOCKS:
        if needle in code:
            return scratch["out"].get(line)
    raise AssertionError(f"no block of docs/tutorial.md contains {needle!r}")


def _readings(path):
    with open(path, encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def test_outputs(scratch):
    """What the blocks made, and the numbers the tutorial quotes (update the prose with them)."""
    if scratch["failed"] is not None:
        pytest.skip(f"a block failed (line {scratch['failed']})")
    w = scratch["dir"] / "work"
    for name in ("sim/campaign.csv", "sim/truth.json", "pred_errormap.csv", "pred_dh.csv",
                 "unc_linear.json", "unc_mc.json", "maps.png", "u_map.png", "comp_commands.csv",
                 "tables/J1_compensation.csv", "tables/J2_compensation.csv", "report/report.html",
                 "report/iso230.json", "run/run.json", "run/events.jsonl",
                 "run/truth.json", "run/result_errormap.json", "run/report/report.html",
                 "py/result_errormap.json"):
        assert (w / name).is_file(), f"work/{name} missing"
    if shutil.which("dot") is not None:
        assert (w / "diagrams" / "paper000_emulated.svg").is_file()

    prose = []

    def assert_quoted(value, quoted, what, about=False):  # collected: one failure lists every drifted number
        prose.append(quoted_problem(value, quoted, what, about))

    dh = json.loads((w / "sim/result_dh.json").read_text())
    em = json.loads((w / "sim/result_errormap.json").read_text())
    assert dh["model"] == "dh" and em["model"] == "errormap"
    # Section 3 prose (the printed lines themselves are checked by the ```output blocks).
    assert_quoted(1e3 * em["residual_rms_mm"], "15.6", "error-map residual RMS, um")
    assert_quoted(1e3 * dh["residual_rms_mm"], "51.5", "D-H residual RMS, um")
    truth = json.loads((w / "sim/truth.json").read_text())
    assert_quoted(truth["L1_mm"], "324.970", "true L1, mm")
    assert_quoted(truth["L2_mm"], "225.004", "true L2, mm")
    assert_quoted(1e3 * (dh["L2_mm"] - truth["L2_mm"]), "24", "D-H L2 bias, um")

    pred = _readings(w / "pred_errormap.csv")
    assert_quoted(float(pred[0]["y_mm"]) - float(pred[1]["y_mm"]), "0.158", "predictions 'apart', mm")
    dh_pred = _readings(w / "pred_dh.csv")
    assert dh_pred[0]["y_mm"] == dh_pred[1]["y_mm"]

    # Section 5 prose: the Monte Carlo numbers (its output is not quoted) and the summary.
    unc = json.loads((w / "unc_linear.json").read_text())
    mc = json.loads((w / "unc_mc.json").read_text())
    assert mc["trials"] == 200
    assert_quoted(1e3 * mc["L1_mm"], "2.69", "MC u(L1), um")
    assert_quoted(1e3 * mc["prediction_expanded_mm"]["max"], "27.2", "MC position U max, um")
    assert_quoted(1e3 * unc["prediction_expanded_mm"]["max"], "28", "linear position U max, um")
    assert_quoted(1e3 * unc["prediction_expanded_mm"]["mean"], "14", "linear position U mean, um")
    assert_quoted(1e3 * unc["reading_std_median_mm"], "15.8", "reading uncertainty, um")

    assert len(_readings(w / "comp_commands.csv")) == 4
    # Section 7: ISO 230-2 values and the validation table of the report.
    iso = json.loads((w / "report/iso230.json").read_text())["axes"]
    for axis, b, b_mean, e in (("J1", "10.7", "9.7", "40.5"), ("J2", "15.4", "14.2", "39.8")):
        assert_quoted(1e3 * iso[axis]["B_deg"], b, f"{axis} B, mdeg")
        assert_quoted(1e3 * iso[axis]["B_mean_deg"], b_mean, f"{axis} mean reversal, mdeg")
        assert_quoted(1e3 * iso[axis]["E_deg"], e, f"{axis} E, mdeg")
    table = _validation_table(w / "report/report.html")
    for model, rms, worst in (("error map", "15.5", "48"), ("D-H", "105", "255")):
        assert_quoted(table["500 random commands", model][0], rms, f"{model} validation RMS, um")
        assert_quoted(table["500 random commands", model][1], worst, f"{model} validation max, um")
    assert_quoted(table["500 random commands", "error map"][2], "13.4", "fitted rotation, mdeg")

    # Section 9-10: the emulated campaign, its beam-loss variant and its identification.
    n_failed = int(_block_output(scratch, "grep -c invalid_reading").split()[-1])
    assert 20 <= n_failed <= 50, f"'About 35 READs fail': {n_failed}"
    run_em = json.loads((w / "run/result_errormap.json").read_text())
    # The emulated run's noise depends on where it was interrupted: "about", "within a few µm".
    assert_quoted(1e3 * run_em["residual_rms_mm"], "15", "emulated residual RMS, um", about=True)
    for name in ("L1_mm", "L2_mm"):  # "within a few standard uncertainties": 4 u (k = 1)
        assert abs(run_em[name] - truth[name]) < 4 * run_em["uncertainty"][name], (name, run_em[name])
    assert_quoted(run_em["dead_paths_mm"][0], "1094.6", "emulated d0_0, mm")
    run_iso = json.loads((w / "run/report/iso230.json").read_text())["axes"]
    assert_quoted(1e3 * run_iso["J1"]["B_mean_deg"], "9.5", "emulated J1 backlash, mdeg", about=True)
    assert_quoted(1e3 * run_iso["J2"]["B_mean_deg"], "14", "emulated J2 backlash, mdeg", about=True)
    rms = _validation_table(w / "run/report/report.html")["500 random commands", "error map"][0]
    prose.append(None if 15 * 0.9 <= rms <= 19 * 1.1 else f"emulated validation RMS: '15 to 19 um', the run gives {rms}")
    drifted = [p for p in prose if p]
    assert not drifted, "update the tutorial's prose:\n" + "\n".join(drifted)

    # The interrupted and resumed emulated run: 130 on SIGINT with the resume hint, all readings
    # on disk once, from three sessions.
    out = _block_output(scratch, "kill -INT")
    assert "exited with status 130" in out and "exited with status 137" in out
    assert "continue with: olti run diagrams/paper000_emulated.yaml --out work/run --resume" in out
    rows = _readings(w / "run/campaign.csv")
    steps = [int(r["step"]) for r in rows]
    assert len(rows) == 1056 and len(set(steps)) == 1056 and steps == sorted(steps)
    assert {r["session"] for r in rows} == {"0", "1", "2"}
    run = json.loads((w / "run/run.json").read_text())
    assert run["sessions"][0]["outcome"] == "interrupted (SIGINT)"  # the kill -9'd one never ended
    assert run["sessions"][-1]["outcome"] == "complete"
