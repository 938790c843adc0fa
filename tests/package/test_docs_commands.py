"""Every doc's commands are run or parsed (issue 24, class 9: docs that drift).

Every ``olti ...`` (and ``python -m olti_drake.cli...``) command line in a code block of README.md and of
every docs/*.md -- fenced blocks of shell kind (```bash, ```console, ```sh, ``` without info, the
tutorial's ```bash-norun / ```bash-needs-dot) and indented code blocks -- is

- **parsed** by the real command-line parser (`olti_drake.cli.verbs.build_parser`, the emulator's own
  parser for ``python -m olti_drake.cli.emulator``), every one of them: a verb or option renamed or removed
  in the package and not in the doc fails here. A synopsis line is parsed in each of its forms: without the
  bracketed optional parts, and with all of them for each listed alternative (``[--criterion max|mean]``);
  a placeholder value (``N``, ``S``) given to a typed option is replaced by a value that option takes;
  ``[fault flags]``-like prose in brackets is left out;
- **run** by a test, in a scratch directory holding symlinks to ``diagrams/``, ``data/``, ``examples/``
  (the paths a reader types at the repository root), when its inputs are the repository's own and it
  is fast enough for the suite: then the numbers the doc quotes about its output are compared with what it
  printed or wrote, within the stated tolerance. ``RUN`` names the test that runs each such command;
  docs/tutorial.md's ```bash blocks are all run by tests/package/test_tutorial.py.

``test_every_doc_command_is_run_or_parsed_only_by_decision`` keeps it so for docs to come: a command line
of any doc must be in ``RUN`` or in ``PARSED_ONLY`` (with the reason it is not run: placeholder inputs, a
device, a run too long for the suite -- measured), so a new doc's commands are classified before it lands.
"""

import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINKED = ("diagrams", "data", "examples")
SHELL_FENCES = {"", "bash", "sh", "shell", "console", "bash-norun", "bash-needs-dot"}
TUTORIAL_RUN_FENCES = {"bash", "bash-needs-dot"}  # tests/package/test_tutorial.py runs these, in order
FENCE = re.compile(r"^```([^\s`]*)\s*$")
OPERATORS = {"&&", "||", ";", "&", "|", "(", ")", ";;"}
COMMAND_START = re.compile(r"(?:^|[;&|(])\s*(?:olti\b|python -m olti_drake\.cli\b)")
SYNOPSIS_GOES_ON = re.compile(r"\s+(\[|--)")  # an indented line of options continues a synopsis line
REDIRECTS = {">", ">>", "<", "2>", "&>", ">&"}

#: Commands a test runs: {doc: {command: the test}} (command: the doc's line, continuations joined, the comment
#: cut, blanks collapsed).
RUN = {
    "README.md": {
        "olti demo": "tests/cli/test_cli.py::test_demo_writes_campaign_and_figures",
    },
    "docs/trials.md": {
        "olti identify data/paper000/campaign.csv --model dh --out dh.json": "test_trials.py::test_trials_doc_block",
        "olti uncertainty dh.json data/paper000/campaign.csv --method mc --trials 1000 --workers 1 --out u1.json":
            "test_trials.py::test_trials_doc_block",
        "olti uncertainty dh.json data/paper000/campaign.csv --method mc --trials 1000 --workers 2 --out u2.json":
            "test_trials.py::test_trials_doc_block",
    },
    "docs/six_axis_campaign.md": {
        "olti simulate diagrams/six_axis.yaml --out six": "test_six_axis_doc_block",
        "olti identify six/campaign.csv --robot ur5 --tool-frame tool0 --tool-offset-mm 40,-25,60 --model errormap "
        "--out six/result.json": "test_six_axis_doc_block",
        "olti predict six/truth.json six/campaign.csv --out six/true_readings.csv": "test_six_axis_doc_block",
    },
    "docs/serial_robots.md": {
        "olti identify data/paper000/campaign.csv --robot scara --tool-frame beam --model dh --out dh.json":
            "test_serial_robots_scara_block",
        "olti identify data/paper000/campaign.csv --robot scara --tool-frame beam --model errormap --grid-step-deg 20 "
        "--out em.json": "test_serial_robots_scara_block",
    },
    "docs/machine_3d.md": {
        "olti multilaterate DIR/campaign.csv --out DIR/ml.json":
            "test_docs_numbers.py::test_the_machine_3d_walk_through_quotes_what_it_prints",
        'olti identify DIR/campaign.csv --model volumetric --tool-offsets-mm "0,0,100;80,0,100;0,80,140" '
        "--out DIR/vol.json": "test_docs_numbers.py::test_the_machine_3d_walk_through_quotes_what_it_prints",
    },
}

#: Commands only parsed, and why they are not run (times measured on the 2-core machine).
PLACEHOLDERS = "placeholder inputs (a synopsis, or files the reader brings)"
PARSED_ONLY = {
    "docs/trials.md": {
        "olti uncertainty RESULT.json CAMPAIGN.csv --method mc --trials 1000 --backend dask --workers 2 --out U.json":
            PLACEHOLDERS + " (the Dask backend's local cluster is run by tests/estimation/test_trials.py on the library)",
        "olti uncertainty RESULT.json CAMPAIGN.csv --method mc --adaptive --backend dask --scheduler tcp://HOST:8786 "
        "--out U.json": "needs a running Dask cluster",
        "olti uncertainty RESULT.json CAMPAIGN.csv --method mc --trials 20000 --backend ray --out U.json":
            "needs a Ray cluster (the ray extra is not in the suite's install)",
    },
    "docs/five_axis.md": {
        "olti run diagrams/scenarios.yaml --scenario machine5_emulated --out run5":
            "9-29 s for 1 000 readings on the five-axis emulator; tests/hardware/test_machine5_run.py runs a 120-reading one, "
            "killed and resumed",
        "olti run diagrams/scenarios.yaml --scenario machine5_emulated --out run5 --resume": "as above",
        'olti identify run5/campaign.csv --machine olti_drake/models/trunnion_ac.urdf --model geometric '
        '--tool-offsets-mm "0,0,0;0,60,30" --out run5/r.json': "needs the run above (tests/hardware/test_machine5_run.py "
                                                                "identifies its run's campaign)",
        "python -m olti_drake.cli.emulator diagrams/machine_5axis.yaml --link /tmp/m5":
            "a device that runs until stopped, on a fixed /tmp path (tests/hardware/test_machine5_run.py starts it)",
        "olti run diagrams/scenarios.yaml --scenario machine5_bench --out bench5": "needs the emulator above",
        "olti identify campaign.csv --machine olti_drake/models/trunnion_ac.urdf --workpiece-frame workpiece "
        "--tool-frame tool --model errormap [--grid-step-deg 15] [--smoothing auto|off|W] --out r.json":
            PLACEHOLDERS + " (run by tests/estimation/test_five_axis_identify.py on simulated campaigns)",
        "olti predict r.json points.csv --out p.csv": PLACEHOLDERS + " (run by tests/estimation/test_five_axis_identify.py)",
        "olti compensate r.json targets.csv --out commands.csv [--cnc siemens|fanuc|heidenhain|linuxcnc|csv --tables "
        "DIR]": PLACEHOLDERS + " (run by tests/model/test_five_axis_compensation.py on a simulated result)",
        "olti uncertainty r.json campaign.csv --method mc [--budget B.yaml] [--trials 200] [--seed 0] --out u.json":
            PLACEHOLDERS + " (run by tests/estimation/test_five_axis_uncertainty.py on simulated campaigns)",
        "olti uncertainty r.json campaign.csv --method linear --out u_linear.json":
            PLACEHOLDERS + " (run by tests/estimation/test_five_axis_uncertainty.py)",
        "olti report r.json [u.json] [--campaign campaign.csv] [--tolerance dispersion=0.005,modification_mm=0.02,"
        "modification_urad=50] --out page": PLACEHOLDERS + " (run by tests/report/test_five_axis_report.py)",
    },
    "docs/six_axis_campaign.md": {
        "olti simulate diagrams/scenarios.yaml --scenario six_axis_mounted --out six_m":
            "too slow for the suite (25 s; 2800 IK aims); its diagram is tested in tests/sim/test_six_axis.py",
    },
    "docs/serial_robots.md": {
        "olti identify campaign.csv --robot ur5 --tool-frame tool0 --tool-offset-mm 40,-25,60 --model errormap "
        "--grid-step-deg 10 --out result.json": PLACEHOLDERS,
        "olti predict result.json held_out.csv --out pred.csv [--outside clamp]": PLACEHOLDERS,
        "olti compensate result.json targets.csv --out commands.csv --tables tables/ --urdf-out ur5_identified.urdf":
            PLACEHOLDERS,
    },
    "docs/machine_3d.md": {
        "olti identify CAMPAIGN.csv --model volumetric --tool-offsets-mm '0,0,100;150,0,100;0,150,140' "
        "[--knot-spacing-mm 50] [--topology serial|table-xy|table-yx|table-y] [--pitch-mm 10] [--budget B.yaml] [--smoothing auto|off] --out R.json":
            PLACEHOLDERS,
        "olti design RESULT.json --regions BOXES.yaml [--stations N] [--criterion max|mean] [--budget B.yaml] "
        "[--step-mm S] [--seed 0] [--starts 3] [--max-sweeps 5] [--min-separation-mm 100] --out DESIGN.json":
            PLACEHOLDERS,
    },
    "docs/runner.md": {
        "olti run diagrams/paper000_emulated.yaml --out run1":
            "11 s on the emulator; tests/package/test_tutorial.py runs it (to work/run), interrupted and resumed",
        "olti run diagrams/paper000_emulated.yaml --out run1 --resume": "as above (tests/package/test_tutorial.py)",
        "python -m olti_drake.cli.emulator --link /tmp/olti":
            "a device that runs until stopped, on a fixed /tmp path (tests/hardware/test_runner.py runs the bench scenario)",
        "olti run diagrams/scenarios.yaml --scenario paper000_bench --out bench1": "needs the emulator above",
        "olti run six.yaml --out run6": "six.yaml is the reader's (base: six_axis.yaml); tests/hardware/test_emulator_nj.py",
        "olti run six.yaml --out run6 --resume": "as above",
        "olti run m3.yaml --out run3":
            "m3.yaml is the reader's (base: machine_3d.yaml); 28 s on the 3D emulator; tests/hardware/test_machine3d_run.py",
        "olti run m3.yaml --out run3 --resume": "as above",
        "olti multilaterate run3/campaign.csv --out run3/ml.json":
            "needs run3 above (the same as machine_3d.md's, run)",
        'olti identify run3/campaign.csv --model volumetric --tool-offsets-mm "0,0,100;80,0,100;0,80,140" '
        "--out run3/vol.json": "needs run3 above (the same as machine_3d.md's, run)",
    },
    "docs/tracker.md": {
        "olti tracker-emulator --port 7000 --reflector-mm 1800,-400,250":
            "a device that runs until stopped, on a fixed port; tests/hardware/test_tracker_emscon.py drives it (port 0)",
        "olti tracker-emulator --port 7000 --scenario six_tracker.yaml": "as above, six_tracker.yaml the reader's",
        "olti run six_tracker.yaml --out run_t": "six_tracker.yaml is the reader's (base: six_axis.yaml); "
                                                "tests/hardware/test_tracker_emscon.py runs it, SIGKILLed and resumed",
        "olti run six_tracker.yaml --out run_t --resume": "as above",
        "olti run bench_tracker.yaml --out run_b": "needs the emulator above; tests/hardware/test_tracker_emscon.py",
    },
    "docs/emulator.md": {
        "python -m olti_drake.cli.emulator [SCENARIO.yaml] [--speed fast|realistic] [--seed N] [--link PREFIX] "
        "[fault flags]": "a device that runs until stopped; tests/hardware/test_emulator.py drives it",
        "python -m olti_drake.cli.emulator --robot ur5 --link /tmp/ur5 [--truth-seed N] [--seed N] [fault flags]":
            "a device that runs until stopped; tests/hardware/test_emulator_nj.py drives it",
        "python -m olti_drake.cli.emulator --robot my_arm.urdf --tool-frame tool0": PLACEHOLDERS,
        "python -m olti_drake.cli.emulator m3.yaml --link /tmp/m3 [--seed N] [--speed realistic] [fault flags]":
            "a device that runs until stopped; tests/hardware/test_machine3d_run.py drives it",
        "python -m olti_drake.cli.emulator diagrams/machine_5axis.yaml --link /tmp/m5 [--seed N] [--speed realistic] "
        "[fault flags]": "a device that runs until stopped; tests/hardware/test_machine5_run.py drives it",
    },
}


# ----------------------------------------------------------------------------- the commands of the docs

def _rel(path):
    return str(Path(path).relative_to(ROOT))


def code_lines(text):
    """[(first line number, info, [lines])] of the code blocks of a Markdown text: fenced blocks (info the
    fence's word) and indented ones (info ``indented``: lines of 4 spaces after a blank line)."""
    blocks, info, start, lines = [], None, 0, []
    prev_blank, indented = True, None
    for n, line in enumerate(text.splitlines(), 1):
        if info is not None:
            if line.rstrip() == "```":
                blocks.append((start, info, lines))
                info = None
            else:
                lines.append(line)
            continue
        m = FENCE.match(line)
        if m:
            if indented:
                blocks.append(indented)
                indented = None
            info, start, lines = m.group(1), n + 1, []
            continue
        if line.startswith("    ") and (indented is not None or prev_blank):
            if indented is None:
                indented = (n, "indented", [])
            indented[2].append(line[4:])
        elif line.strip() and indented is not None:
            blocks.append(indented)
            indented = None
        prev_blank = not line.strip()
    if indented:
        blocks.append(indented)
    assert info is None, f"the block opened at line {start - 1} is never closed"
    return blocks


def _is_command(words):
    return bool(words) and (words[0] == "olti" or words[:3] in (["python", "-m", "olti_drake.cli"],
                                                                ["python", "-m", "olti_drake.cli.emulator"]))


def split_commands(line):
    """The commands of one shell line: split at its operators (&&, ;, |, &), the comment and redirections cut;
    a bracketed synopsis part (``[--topology serial|table-xy]``) is kept whole."""
    protected = re.sub(r"\[[^\[\]]*\]", lambda m: m.group(0).replace("|", "\0"), line)
    lex = shlex.shlex(protected, posix=True, punctuation_chars=";&|()<>")
    lex.whitespace_split, lex.commenters = True, "#"
    out, words, skip = [], [], False
    for tok in lex:
        if skip:
            skip = False
        elif tok in OPERATORS:
            out.append(words)
            words = []
        elif tok in REDIRECTS or re.fullmatch(r"\d?>>?&?\d?", tok):
            skip = not tok.endswith(("&1", "&2"))
        else:
            words.append(tok.replace("\0", "|"))
    out.append(words)
    return [w for w in out if _is_command(w)]


def doc_commands(path):
    """[(line number, fence info, argv, first line of its block)] of the olti commands in the code blocks of a doc."""
    out = []
    for start, info, lines in code_lines(Path(path).read_text(encoding="utf-8")):
        if info not in SHELL_FENCES and info != "indented":
            continue
        k = 0
        while k < len(lines):
            n, text = start + k, lines[k]
            while k + 1 < len(lines) and (text.rstrip().endswith("\\") or SYNOPSIS_GOES_ON.match(lines[k + 1])):
                k += 1
                text = text.rstrip().rstrip("\\") + " " + lines[k].strip()
            k += 1
            text = re.sub(r"^\s*\$\s+", "", text)  # a console prompt
            if not COMMAND_START.search(text):
                continue
            try:
                commands = split_commands(text)
            except ValueError as e:
                raise AssertionError(f"{_rel(path)}:{n}: a command line the shell cannot split ({e})") from None
            for argv in commands:
                out.append((n, info, argv, start))
    return out


def _words(command):
    return [w.replace("\0", "|") for w in shlex.split(re.sub(r"\[[^\[\]]*\]",
                                                             lambda m: m.group(0).replace("|", "\0"), command))]


def _table_words(table):
    return {doc: {tuple(_words(c)): why for c, why in cmds.items()} for doc, cmds in table.items()}


ALL = [(_rel(p), n, info, argv, block) for p in DOCS for n, info, argv, block in doc_commands(p)]


# ----------------------------------------------------------------------------- parsing by the real parser

_PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*")


def variants(argv):
    """The forms of a synopsis: without its [optional] parts, then with all of them for each alternative
    (``a|b``: the first, then the second, ...). Bracketed prose (not an option, not one word) is left out."""
    text = " ".join(shlex.quote(w) if " " in w and not w.startswith("[") else w for w in argv)
    groups, depth, cur, plain = [], 0, "", []
    for ch in text:  # top-level [ ... ] groups; nested brackets stay inside their group
        if ch == "[":
            if depth == 0:
                plain.append("\1")
                cur = ""
            else:
                cur += ch
            depth += 1
        elif ch == "]" and depth:
            depth -= 1
            if depth == 0:
                groups.append(cur)
            else:
                cur += ch
        elif depth:
            cur += ch
        else:
            plain.append(ch)
    if not groups:
        return [list(argv)]
    template = "".join(plain)
    kept = [g.strip() if g.strip().startswith("-") or " " not in g.strip() else "" for g in groups]
    n_alt = max([len(w.split("|")) for g in kept for w in g.split()] + [1])
    out = []
    for k in [None, *range(n_alt)]:
        parts = iter([] if k is None else
                     [" ".join(w.split("|")[min(k, len(w.split("|")) - 1)] for w in g.split()) for g in kept])
        text_k = re.sub("\1", lambda m: next(parts, ""), template)
        out.append(shlex.split(re.sub(r"\[|\]", " ", text_k)))
    return out


def _substitute(parser, argv):
    """``--stations N`` -> a value the option's type takes (the parser's own actions say which option is typed)."""
    actions = {}
    for a in parser._actions:
        for s in a.option_strings:
            actions[s] = a
        if isinstance(a, argparse._SubParsersAction) and argv and argv[0] in a.choices:
            return [argv[0]] + _substitute(a.choices[argv[0]], argv[1:])
    out = list(argv)
    for i in range(1, len(out)):
        a = actions.get(out[i - 1])
        if a is not None and a.type is not None and _PLACEHOLDER.fullmatch(out[i]):
            for sample in ("1", "4", "10", "0.5", "0"):
                try:
                    a.type(sample)
                except (argparse.ArgumentTypeError, ValueError, TypeError):
                    continue
                out[i] = sample
                break
    return out


class _Parsed(Exception):
    pass


def parse_problem(argv, monkeypatch):
    """None if the real parser takes ``argv`` (a command of a doc, one form), else its message."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    if argv[:3] == ["python", "-m", "olti_drake.cli"]:
        argv = ["olti", *argv[3:]]
    err = io.StringIO()
    try:
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            if argv[0] == "olti":
                from olti_drake.cli import verbs

                parser = verbs.build_parser()
                args = parser.parse_args(verbs._join_signed_values(_substitute(parser, argv[1:])))
                empty = verbs._empty_argument(parser, args)
                return None if empty is None else empty
            module = argv[2]
            assert module == "olti_drake.cli.emulator", f"no parser known for {module}"
            from olti_drake.cli import emulator

            original = argparse.ArgumentParser.parse_args

            def parse_only(self, args=None, namespace=None):
                raise _Parsed(original(self, _substitute(self, list(args)), namespace))

            monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_only)
            try:
                emulator.main(argv[3:])
            except _Parsed:
                return None
            finally:
                monkeypatch.undo()
            return "the emulator's parser was never reached"
    except SystemExit as e:
        return err.getvalue().strip() or f"exit {e.code}"


@pytest.mark.parametrize("doc,line,info,argv,block", ALL, ids=[f"{d}:{n}" for d, n, *_ in ALL])
def test_every_doc_command_parses(doc, line, info, argv, block, monkeypatch):
    problems = []
    for form in variants(argv):
        p = parse_problem(form, monkeypatch)
        if p:
            problems.append(f"{' '.join(form)}: {p}")
    assert not problems, f"{doc}:{line}: the command line does not parse; update the doc:\n" + "\n".join(problems)


def test_the_parse_check_catches_a_renamed_option_and_verb(monkeypatch):
    assert parse_problem(["olti", "identify", "c.csv", "--model", "dh", "--out", "r.json"], monkeypatch) is None
    typo = ["olti", "identify", "c.csv", "--model", "dh", "--modle", "x", "--out", "r.json"]
    assert "unrecognized" in parse_problem(typo, monkeypatch)
    assert "invalid choice" in parse_problem(["olti", "identfy", "c.csv"], monkeypatch)
    assert parse_problem(["olti", "design", "r.json", "--regions", "b.yaml", "--stations", "N", "--out", "d.json"],
                         monkeypatch) is None  # a placeholder value is replaced by one the option takes
    assert parse_problem(["python", "-m", "olti_drake.cli.emulator", "--seed", "N", "--link", "/tmp/x"],
                         monkeypatch) is None
    assert "unrecognized" in parse_problem(["python", "-m", "olti_drake.cli.emulator", "--sped", "fast"], monkeypatch)
    assert [" ".join(v) for v in variants(_words("olti x R [--a 1] [--c max|mean] [fault flags] --out D"))] == [
        "olti x R --out D", "olti x R --a 1 --c max --out D", "olti x R --a 1 --c mean --out D"]


def test_every_doc_command_is_run_or_parsed_only_by_decision():
    """A command line of any doc is run by a named test (RUN) or parsed only for a stated reason (PARSED_ONLY);
    the tutorial's run blocks are run by tests/package/test_tutorial.py, its ```bash-norun blocks parsed only."""
    run, parsed_only = _table_words(RUN), _table_words(PARSED_ONLY)
    seen, unclassified = set(), []
    for doc, line, info, argv, _ in ALL:
        key = tuple(argv)
        seen.add((doc, key))
        if doc == "docs/tutorial.md" and info in TUTORIAL_RUN_FENCES | {"bash-norun"}:
            continue
        if key not in run.get(doc, {}) and key not in parsed_only.get(doc, {}):
            unclassified.append(f"{doc}:{line}: {' '.join(argv)}")
    assert not unclassified, ("commands in the docs neither run by a test (RUN) nor parsed only for a stated reason "
                              "(PARSED_ONLY) in tests/package/test_docs_commands.py:\n" + "\n".join(unclassified))
    stale = [f"{doc}: {' '.join(k)}" for table in (run, parsed_only) for doc, cmds in table.items() for k in cmds
             if (doc, k) not in seen]
    assert not stale, "RUN / PARSED_ONLY name commands no doc has any more:\n" + "\n".join(stale)
    for doc, cmds in RUN.items():  # the test RUN names exists
        for test in set(cmds.values()):
            path, _, name = test.rpartition("::") if "::" in test else (__file__, "", test)
            path = ROOT / path if "/" in path else next((ROOT / "tests").glob(f"*/{Path(path).name}"))
            assert f"def {name}(" in path.read_text(encoding="utf-8"), f"RUN[{doc!r}]: no test {test}"
    assert len(ALL) >= 40 and {d for d, *_ in ALL} >= {"README.md", "docs/tutorial.md", "docs/runner.md"}


# ----------------------------------------------------------------------------- verbs and options in the prose

#: Inline ``--flags`` of the docs that are not olti's: Chromium's (README, the headless-browser test).
NOT_OLTI_FLAGS = {"--headless", "--no-sandbox", "--disable-gpu", "--use-gl", "--use-angle"}
_FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def _olti_subparsers():
    from olti_drake.cli import verbs

    parser = verbs.build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _emulator_options(monkeypatch):
    from olti_drake.cli import emulator

    def grab(self, args=None, namespace=None):
        raise _Parsed(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", grab)
    try:
        emulator.main([])
    except _Parsed as e:
        return set(e.args[0]._option_string_actions)
    finally:
        monkeypatch.undo()
    raise AssertionError("the emulator's parser was never reached")


def _inline_spans(path):
    """[(line, code span)] of a doc outside its fenced blocks."""
    text = re.sub(r"```.*?```", lambda m: "\n" * m.group(0).count("\n"), Path(path).read_text(encoding="utf-8"),
                  flags=re.S)
    return [(text[:m.start()].count("\n") + 1, m.group(1)) for m in re.finditer(r"`([^`\n]+(?:\n[^`\n]+)?)`", text)]


def test_verbs_and_options_named_in_the_prose_exist(monkeypatch):
    """The prose's `olti VERB ... --option` spans (README's command table included) name a verb and options of
    that verb; a bare `--option` span is an option of some verb or of the emulator. A renamed or removed option
    the prose still names fails here."""
    verbs = _olti_subparsers()
    every = set().union(*(set(p._option_string_actions) for p in verbs.values())) | _emulator_options(monkeypatch)
    problems, n = [], 0
    for path in DOCS:
        for line, span in _inline_spans(path):
            words = span.split()
            if words[0] == "olti" and len(words) > 1 and re.fullmatch(r"[a-z]+", words[1]):
                n += 1
                if words[1] not in verbs:
                    problems.append(f"{_rel(path)}:{line}: `{span}`: no verb {words[1]!r}")
                    continue
                own = set(verbs[words[1]]._option_string_actions)
                problems += [f"{_rel(path)}:{line}: `{span}`: olti {words[1]} has no {o}"
                             for o in _FLAG.findall(span) if o not in own]
            elif words[0].startswith("--"):
                o = _FLAG.match(words[0])
                if o and o.group(1) not in every and o.group(1) not in NOT_OLTI_FLAGS:
                    problems.append(f"{_rel(path)}:{line}: `{span}`: no verb of olti nor the emulator has {o.group(1)}")
    assert n >= 80, n
    assert not problems, "the docs name verbs or options the command line does not have:\n" + "\n".join(problems)


def test_the_readme_command_table_and_force_list_are_the_parsers():
    """README.md's command table has a row for every verb of the parser (and no other), and its list of the verbs
    that take --force is the parser's."""
    verbs = _olti_subparsers()
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| `olti ([\w-]+)", text, re.M))   # verbs may have hyphens (tracker-emulator)
    assert rows == set(verbs), f"README's command table: rows {sorted(rows)}, the parser's verbs {sorted(verbs)}"
    m = re.search(r"the verbs\s+that write results take it: (.*?)\);", text, re.S)
    assert m, "README.md: the list of the verbs that take --force is gone"
    listed = set(re.findall(r"`(\w+)`", m.group(1)))
    force = {v for v, p in verbs.items() if "--force" in p._option_string_actions}
    assert listed == force, f"README lists {sorted(listed)} as taking --force, the parser: {sorted(force)}"


# ----------------------------------------------------------------------------- the commands a test runs here

@pytest.fixture
def scratch(tmp_path):
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    return tmp_path


def run_block(doc, needle, cwd, subst=None, extra=(), only=None):
    """Run, in order, the commands RUN lists of ``doc``'s code block that holds ``needle`` (the block's others are
    PARSED_ONLY), in ``cwd``; ``subst``: the doc's placeholder directory ``DIR`` -> a real one; ``extra``: options
    added to every command; ``only``: run only the commands holding this text. {the doc's command: what it printed}."""
    cmds = [(n, argv, block) for d, n, _, argv, block in ALL if d == doc]
    blocks = {block for _, argv, block in cmds if needle in " ".join(argv)}
    assert len(blocks) == 1, f"{doc}: {len(blocks)} blocks with a command holding {needle!r}"
    run = _table_words(RUN)[doc]
    env = dict(os.environ, MPLBACKEND="Agg", PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    out = {}
    for n, argv, block in cmds:
        if block not in blocks or tuple(argv) not in run or (only and only not in " ".join(argv)):
            continue
        words = [re.sub(r"\bDIR\b", str(subst), w) if subst else w for w in argv] + list(extra)
        proc = subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, f"{doc}:{n}: {' '.join(words)} exited {proc.returncode}\n{proc.stderr}"
        out[" ".join(argv)] = proc.stdout + proc.stderr
    assert out, f"{doc}: RUN lists no command of the block holding {needle!r}"
    return out


def quoted_ok(value, quoted):
    """``value`` is the number ``quoted`` within one unit of its last quoted digit."""
    unit = 10.0 ** -len(quoted.split(".")[1]) if "." in quoted else 1.0
    return abs(float(value) - float(quoted)) <= 1.000001 * unit


def _flat(doc):
    return " ".join((ROOT / doc).read_text(encoding="utf-8").split())


def test_six_axis_doc_block(scratch):
    """docs/six_axis_campaign.md's block: the floor-tracer campaign simulated, identified, and its truth
    predicting the readings (to the reading noise); the counts and the noise the doc quotes."""
    out = run_block("docs/six_axis_campaign.md", "six_axis.yaml --out six", scratch)
    text = _flat("docs/six_axis_campaign.md")
    sim = out["olti simulate diagrams/six_axis.yaml --out six"]
    m = re.search(r"(\d+) readings \((\d+) valid, (\d+) beam lost\)", sim)
    poses = re.search(r"plan: (\d+) poses", sim)
    assert m and poses, sim
    readings, valid = int(m.group(1)), int(m.group(2))
    q = re.search(r"readable from ≥ 2 heads: (\d+) poses, (\d+) readings\.", text)
    assert q, "docs/six_axis_campaign.md: the shipped scenario's pose and reading counts are gone"
    assert (int(poses.group(1)), readings) == (int(q.group(1)), int(q.group(2)))
    q = re.search(r"On the shipped scenario \((\d+) valid readings", text)
    assert q and int(q.group(1)) == valid
    q = re.search(r"--out six # floor tracers, ~(\d+) readings", text)
    assert q and abs(readings - int(q.group(1))) <= 0.05 * int(q.group(1))
    assert (scratch / "six" / "result.json").is_file()
    pred = out["olti predict six/truth.json six/campaign.csv --out six/true_readings.csv"]
    m = re.search(r"predicted - read RMS ([\d.]+) um", pred)
    q = re.search(r"the shipped campaign: predicted − read RMS ([\d.]+) µm", text)
    assert m and q, (pred, "docs/six_axis_campaign.md: the truth's predicted - read RMS is gone")
    assert quoted_ok(float(m.group(1)), q.group(1)), f"the doc says {q.group(1)} um, olti predict prints {m.group(1)}"
    # the reading noise is the paper-000 budget's (000 Table 2), which the doc names with it
    from olti_drake.estimation.serial_plan import reading_uncertainty_mm
    from olti_drake.io.budget import load_budget

    u = 1e3 * reading_uncertainty_mm(load_budget(ROOT / "data" / "budget_paper000.yaml"))
    q = re.search(r"the reading noise of its budget \(000 Table 2, u = ([\d.]+) µm\)", text)
    assert q and quoted_ok(u, q.group(1)), u
    assert 0.8 * u <= float(m.group(1)) <= 1.2 * u
    q = re.search(r"\(errormap: at the reading noise, the scenario's budget of 000 Table 2, u = ([\d.]+) µm; the truth "
                  r"itself predicts the readings to ([\d.]+) µm RMS\)", text)  # the demo's paragraph
    assert q and quoted_ok(u, q.group(1)) and quoted_ok(float(m.group(1)), q.group(2)), "the demo's paragraph"


def test_serial_robots_scara_block(scratch):
    """docs/serial_robots.md's SCARA-as-a-model-file block runs on the shipped campaign; the model keeps the
    parameters the doc names (6 in-plane for D-H) and D-H's residual is the SCARA path's (tutorial: 51.5 µm)."""
    import json

    out = run_block("docs/serial_robots.md", "--robot scara --tool-frame beam --model dh", scratch)
    assert len(out) == 2
    dh = json.loads((scratch / "dh.json").read_text())
    em = json.loads((scratch / "em.json").read_text())
    assert dh["model"] == "dh" and em["model"] == "errormap"
    text = _flat("docs/serial_robots.md")
    q = re.search(r"The SCARA keeps (\d+): (.*?) and `(\w+)`; `J2_offset_deg` \(θ20\) \"trades with (\w+)\"", text)
    assert q, "docs/serial_robots.md: the sentence naming the parameters the SCARA keeps is gone"
    kept = re.findall(r"`(\w+)`", q.group(2)) + [q.group(3)]
    assert len(kept) == int(q.group(1))
    dropped = {d["parameter"]: d["reason"] for d in dh["dropped"]}
    have = [k for k in kept if k in dh or (k.startswith("tool_") and k not in dropped)]
    assert have == kept and not set(kept) & set(dropped), (kept, sorted(dropped))
    assert dropped["J2_offset_deg"] == f"trades with {q.group(4)}"
    q = re.search(r'with the reason "(out of the plane: .*?)", then ranks', text)
    assert q and dropped["tool_z_mm"] == q.group(1)
