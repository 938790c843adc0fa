"""The calibration report of a five-axis machine (``olti-machine5/1``; issue 25, item 7).

``olti report R.json [UNC.json] [--campaign C.csv] [--tolerance dispersion=0.005,...]``: one section per thing a
calibration engineer checks:

* the **location errors** of every rotary axis (ISO 230-7 names) with u and U = k·u (the uncertainty file's, or
  the result's own linear ones), and what was held at 0 with the reason;
* per rotary axis one figure of its six **error motions** vs the commanded angle, forward and reverse branches,
  each with its U band;
* the **residuals** (with the campaign: the result re-solved on it,
  :func:`~olti_drake.estimation.five_axis_uncertainty.identification_at_result`) per reading kind -- distances,
  R-test nests, tracker points;
* a **KinematicsOpt-style acceptance summary** (after HEIDENHAIN's cycle 451 protocol): the *dispersion* (the
  residuals' standard deviation: how well the identified kinematics explain the readings) and the *maximum
  modification* (the largest location error the result proposes to correct, linear and angular), each with a
  verdict when ``--tolerance`` gives its threshold (:data:`TOLERANCES`);
* **BK check paths** (ISO 10791-6 BK-type paths around a ball, :func:`olti_drake.model.five_axis_compensation.
  bk_check`) simulated on the identified machine before and after compensation -- "not computed" when that
  function is not available;
* the result's notes, gauge and warnings.

Units: mm and µrad in the file; the page shows lengths in µm, angles in µrad, commands in deg.
"""

import os

import numpy as np

from olti_drake.errors import InputError
from olti_drake.report import page as ui

#: Every figure the five-axis page may write (html.OUTPUT_NAMES includes them).
FIGURES = ("fig_motions_A.png", "fig_motions_B.png", "fig_motions_C.png", "fig_residuals.png")
#: ``--tolerance`` names of the acceptance summary and their units in the option (the page shows µm, µrad).
TOLERANCES = {"dispersion": "mm", "modification_mm": "mm", "modification_urad": "urad"}
#: The keys of a five-axis result an uncertainty file must match in shape.
VALUE_KEYS = ("location_errors", "error_motions", "tool_offset_errors_mm")
#: Poses per sweep of a BK path (each path goes there and back).
BK_STEPS = 19


def _shown(v, unit):
    """mm -> µm, µrad as is."""
    return (1e3 if unit == "mm" else 1.0) * np.asarray(v, float)


def _unit_of(name: str) -> str:
    return "mm" if name.endswith("_mm") else "urad"


def _page_unit(unit: str) -> str:
    return "µm" if unit == "mm" else "µrad"


def location_role(name: str) -> str:
    """What a location error E_<c>0<L> is (ISO 230-7): a radial or axial position of axis L's average line, its
    orientation about c, or its zero angle."""
    from olti_drake.model.five_axis import LINEAR, ROTARY

    c, L = name[2], name[4]
    if c == L:
        return f"zero angle of {L}"
    if c in LINEAR:
        return f"{'axial' if LINEAR.index(c) == ROTARY.index(L) else 'radial'} position of {L} in {c}"
    return f"orientation of {L} about {c}"


def motion_role(name: str) -> str:
    """What an error motion E_<c><L> is: radial, axial, tilt or angular positioning of rotary axis L."""
    from olti_drake.model.five_axis import LINEAR, ROTARY

    c, L = name[2], name[3]
    if c == L:
        return "angular positioning"
    if c in LINEAR:
        return "axial" if LINEAR.index(c) == ROTARY.index(L) else "radial"
    return "tilt"


# -- inputs -------------------------------------------------------------------------------------------------
def tolerances_of(given) -> dict:
    """The acceptance thresholds of ``--tolerance`` (name -> value in :data:`TOLERANCES`' units); another name is
    refused in one line."""
    given = dict(given or {})
    bad = [n for n in given if n not in TOLERANCES]
    if bad:
        raise InputError(f"--tolerance {bad[0]}: a five-axis report takes " + ", ".join(
            f"{n} ({u})" for n, u in TOLERANCES.items()))
    return given


def check_uncertainty_file(unc: dict, raw: dict, unc_path, result_path) -> None:
    """The uncertainty file must be of this result: its ``result_sha256`` (``olti uncertainty`` writes it) the
    result file's, its keys and shapes the result's."""
    from olti_drake.io.five_axis_io import file_sha256

    stated = unc.get("result_sha256")
    if stated is not None and stated != file_sha256(result_path):
        raise InputError(f"{os.fspath(unc_path)}: the uncertainty of another result ({unc.get('result', '?')}, sha256 "
                         f"{str(stated)[:12]}...), not of {os.fspath(result_path)}")
    numeric = dict(raw, error_motions={n: {b: m[b] for b in ("forward", "reverse") if b in m}
                                       for n, m in (raw.get("error_motions") or {}).items()})
    ui.check_uncertainty(unc, numeric, VALUE_KEYS, unc_path, result_path)


# -- figures ------------------------------------------------------------------------------------------------
def plot_axis_motions(raw: dict, std: dict, axis: str, k: float, path):
    """The six error motions of rotary axis ``axis`` vs its commanded angle: forward and reverse branches, each
    with its U = k·u band (µm, µrad)."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    names = [n for n, m in raw["error_motions"].items() if m["axis"] == axis]
    fig, axes = ui.axis_panels(plt, len(names), 3.2)
    held = set(raw.get("held", ()))
    for ax, name in zip(axes, names):
        m, u = raw["error_motions"][name], std["error_motions"][name]
        q = np.asarray(m["grid_deg"], float)
        for branch, colour in (("forward", "tab:blue"), ("reverse", "tab:orange")):
            if branch not in m:
                continue
            v, U = _shown(m[branch], m["unit"]), k * _shown(u[branch], m["unit"])
            ax.fill_between(q, v - U, v + U, color=colour, alpha=0.2)
            ax.plot(q, v, marker=".", color="0.5" if name in held else colour, ls="--" if name in held else "-",
                    label=f"{branch}" + (" (held at 0)" if name in held else f", U (k = {k:g}) band"))
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel=f"{axis} command, deg", ylabel=f"{name}, {_page_unit(m['unit'])}",
               title=f"{name}: {motion_role(name)}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Error motions of the {axis} axis (ISO 230-7), forward and reverse, with U (k = {k:g}) bands",
                 fontsize=10)
    return _save(fig, plt, path)


# -- sections ----------------------------------------------------------------------------------------------
def _header(page, raw, result_path, unc, unc_path, campaign_path, note):
    m = raw["machine"]
    page.add("<h1>Calibration report: five-axis machine tool (ISO 230-7 location errors and error motions)</h1>")
    info = [("result", os.fspath(result_path)), ("format", raw["format"]),
            ("machine", f"{m['file']} (axes {', '.join(m['axes'])}; frames {m['workpiece_frame']} → "
                        f"{m['tool_frame']})"),
            ("model", raw["model"]), ("readings", raw.get("n_readings", "—")),
            ("residual RMS", f"{1e3 * float(raw['residual_rms_mm']):.3f} µm"),
            ("uncertainty", f"{os.fspath(unc_path)} ({unc.get('method', '?')})" if unc is not None else
             f"the result's own ({raw['uncertainty'].get('method', 'linear')})")]
    info += ui.fit_rows(raw)
    info += [("note", note)] if note else []
    info.append(("campaign", os.fspath(campaign_path) if campaign_path else "—"))
    page.header_rows = info


def _location_section(page, raw, std, k, unc_path):
    page.add("<h2>Location errors (ISO 230-7)</h2>")
    page.source(None, columns={4: unc_path, 5: unc_path} if unc_path else None)
    dropped = raw.get("dropped", {})
    rows = []
    for name, v in raw["location_errors"].items():
        unit, u = _unit_of(name), std["location_errors"][name]
        held = name in raw.get("held", ())
        rows.append((name, location_role(name), f"{_shown(v, unit):+.3f}", _page_unit(unit),
                     "—" if held else f"{_shown(u, unit):.3f}", "—" if held else f"{k * _shown(u, unit):.3f}",
                     f"held at 0: {dropped.get(name, 'not separable')}" if held else "identified"))
    page.add(ui.table(["location error", "meaning", "value", "unit", "u (k = 1)", f"U (k = {k:g})", "status"], rows,
                      left=(0, 1, 3, 6)))
    page.add(ui.p("Each location error is a small transform of the rotary axis' average line in its carrier, in the "
                  "tool-relative-to-workpiece sense (docs/five_axis.md); held ones are not separable by the "
                  "campaign and their effect is carried by those they trade with."))


def _motions_section(page, raw, std, k, unc_path):
    page.add("<h2>Error motions of the rotary axes</h2>")
    page.source(None, columns={6: unc_path} if unc_path else None)
    motions = raw.get("error_motions") or {}
    if not motions:
        page.add(ui.p(f"Model {raw['model']}: no error motions were identified (olti identify --model errormap "
                      f"identifies them).", "note"))
        return
    rows = []
    for name, m in motions.items():
        v = np.concatenate([_shown(m[b], m["unit"]) for b in ("forward", "reverse") if b in m])
        U = k * np.concatenate([_shown(std["error_motions"][name][b], m["unit"]) for b in ("forward", "reverse")
                                if b in m])
        rows.append((name, m["axis"], motion_role(name), _page_unit(m["unit"]), f"{v.min():+.3f}", f"{v.max():+.3f}",
                     f"{U.max():.3f}", "held at 0" if name in raw.get("held", ()) else "identified"))
    page.add(ui.table(["motion", "axis", "meaning", "unit", "min", "max", f"max U (k = {k:g})", "status"], rows,
                      left=(0, 1, 2, 3, 7)))
    for axis in raw["machine"]["axes"]:
        if any(m["axis"] == axis for m in motions.values()):
            page.figure(lambda p, a=axis: plot_axis_motions(raw, std, a, k, p), f"fig_motions_{axis}.png",
                        f"The six error motions of the {axis} axis, forward and reverse, with U (k = {k:g}) bands")


def _linear_section(page, raw, k):
    """The linear axes as the result has them: identified (the 18 motions' and 3 squareness errors' range of stated
    values and largest U, from the result's covariance), fixed from a volumetric result, or perfect."""
    page.add("<h2>Error motions and squareness of the linear axes</h2>")
    lin = raw.get("linear")
    if raw.get("linear_from"):
        page.add(ui.p(f"Held fixed from the volumetric result {raw['linear_from'].get('file')} (not estimated; its "
                      f"covariance is in every u)."))
        return
    if not lin:
        page.add(ui.p("Taken as perfect: no linear-axis errors in the model (olti identify --linear identify or "
                      "--linear RESULT.json gives them; the notes say why).", "note"))
        return
    page.source(None)
    unc, held, rows = raw["uncertainty"]["linear"], raw.get("held", ()), []
    for name, m in lin["error_motions"].items():
        v, U = _shown(m["values"], m["unit"]), k * _shown(unc["error_motions"][name]["values"], m["unit"])
        rows.append((name, m["axis"], m["role"], _page_unit(m["unit"]), f"{v.min():+.3f}", f"{v.max():+.3f}",
                     f"{U.max():.3f}", "held at 0" if name in held else "identified"))
    for name, v in lin["squareness_urad"].items():
        U = k * unc["squareness_urad"][name]
        rows.append((name, "", "squareness", "µrad", f"{v:+.3f}", f"{v:+.3f}", f"{U:.3f}",
                     "held at 0" if f"{name}_urad" in held else "identified"))
    page.add(ui.table(["motion", "axis", "meaning", "unit", "min", "max", f"max U (k = {k:g})", "status"], rows,
                      left=(0, 1, 2, 3, 7)))
    q = lin["error_motions"]["E_XX"]["positions_mm"]
    page.add(ui.p(f"Identified with the rotary axes: clamped cubic B-splines on knots every "
                  f"{raw['error_model']['knot_spacing_mm']:g} mm, values stated every {q[1] - q[0]:g} mm of each "
                  f"travel (the result's key linear); U from the result's covariance."))


def residuals_by_kind(ident, fit) -> dict:
    """{kind: (residual per reading mm, group labels, residual rows mm)}: each reading kind's own residuals
    (unscaled), a nest or tracker reading by the norm of its x, y, z residual (its rows: the three)."""
    out = {}
    for kind, r in zip(ident.kinds, ident.measurement.unscaled(fit.residuals)):
        rows = ident.campaign.kind == kind
        per = r if kind == "distance" else np.linalg.norm(r.reshape(-1, 3), axis=1)
        out[kind] = (per, ident.campaign.group[rows], r)
    return out


def _residual_section(page, raw, fitted, campaign_path):
    page.add("<h2>Residuals</h2>")
    if fitted is None:
        page.add(ui.p(f"Residual RMS {1e3 * float(raw['residual_rms_mm']):.3f} µm over {raw.get('n_readings', '?')} "
                      f"readings (the result's). Give the campaign (--campaign) for the residuals per reading kind.",
                      "note"))
        return None
    page.source(campaign_path)
    by_kind = residuals_by_kind(*fitted)
    what = {"distance": "distances (station)", "nest": "R-test nests (|r| of x, y, z)",
            "tracker": "tracker points (|r| of x, y, z)"}
    rows = [(what[kind], r.size, f"{1e3 * np.sqrt(np.mean(r ** 2)):.3f}", f"{1e3 * np.std(comp):.3f}",
             f"{1e3 * np.max(np.abs(r)):.3f}") for kind, (r, _, comp) in by_kind.items()]
    page.add(ui.p(f"Reading minus the identified model's reading of every valid reading of {os.fspath(campaign_path)}, "
                  f"the result re-solved on it (stations, nests and tracker frames restored). µm."))
    page.add(ui.table(["readings", "n", "RMS", "standard deviation (x, y, z each)", "max |r|"], rows))
    r = np.concatenate([v[0] for v in by_kind.values()])
    group = np.concatenate([[f"{kind} {g}" for g in v[1]] for kind, v in by_kind.items()])
    page.figure(lambda path: ui.plot_residuals(np.arange(r.size), r, group, "readings of", path), "fig_residuals.png",
                "Residuals per reading kind and station / nest / tracker set-up")
    return by_kind


def acceptance(raw, std, k, by_kind=None, tolerances=None) -> dict:
    """The KinematicsOpt-style summary: ``dispersion_mm`` (the residuals' standard deviation: of every reading
    kind's own residuals with the campaign, else the result's residual RMS), the ``modification`` per unit (the
    largest |location error| identified, its name, U and whether it exceeds U), and the ``verdicts`` of the
    given ``tolerances`` (:data:`TOLERANCES`), one sentence each."""
    if by_kind:
        r = np.concatenate([v[2] for v in by_kind.values()])
        dispersion, basis = float(np.std(r)), "standard deviation of every reading's residual (x, y, z each)"
    else:
        dispersion, basis = float(raw["residual_rms_mm"]), "the result's residual RMS"
    free = {n: v for n, v in raw["location_errors"].items() if n not in raw.get("held", ())}
    modification = {}
    for unit in ("mm", "urad"):
        names = [n for n in free if _unit_of(n) == unit]
        if names:
            n = max(names, key=lambda a: abs(free[a]))
            U = k * std["location_errors"][n]
            modification[unit] = {"name": n, "value": free[n], "U": U, "significant": abs(free[n]) > U}
    verdicts = []
    t = tolerances or {}
    if "dispersion" in t:
        ok = dispersion <= t["dispersion"]
        verdicts.append(f"dispersion {1e3 * dispersion:.2f} µm {'≤' if ok else '>'} {1e3 * t['dispersion']:g} µm: "
                        + ("PASS, the identified kinematics explain the readings" if ok else
                           "FAIL, the readings scatter beyond the tolerance (check the set-up, the model's family)"))
    for unit, key in (("mm", "modification_mm"), ("urad", "modification_urad")):
        if key in t and unit in modification:
            m = modification[unit]
            within = abs(m["value"]) <= t[key]
            shown, lim = _shown(abs(m["value"]), unit), _shown(t[key], unit)
            verdicts.append(f"maximum modification {m['name']} {shown:.2f} {_page_unit(unit)} "
                            f"{'≤' if within else '>'} {lim:g} {_page_unit(unit)}: "
                            + ("within tolerance, no correction of the kinematics needed" if within else
                               "exceeds the tolerance: correct the kinematics (olti compensate, --cnc tables)"))
    return {"dispersion_mm": dispersion, "dispersion_basis": basis, "modification": modification,
            "verdicts": verdicts}


def _acceptance_section(page, raw, std, k, by_kind, tolerances, unc_path, campaign_path):
    page.add("<h2>Acceptance summary (KinematicsOpt style)</h2>")
    a = acceptance(raw, std, k, by_kind, tolerances)
    page.source(campaign_path if by_kind else None)
    page.add(ui.table(["quantity", "of", "value"], [("dispersion", a["dispersion_basis"],
                                                      f"{1e3 * a['dispersion_mm']:.3f} µm")], left=(0, 1)))
    page.source(None, columns={3: unc_path} if unc_path else None)
    rows = [(f"maximum modification ({'linear' if unit == 'mm' else 'angular'})",
             f"{m['name']}: {location_role(m['name'])}", f"{_shown(m['value'], unit):+.3f} {_page_unit(unit)}",
             f"{_shown(m['U'], unit):.3f} {_page_unit(unit)}" + (" (significant)" if m["significant"] else
                                                                " (within U)"))
            for unit, m in a["modification"].items()]
    page.add(ui.table(["quantity", "of", "value", f"U (k = {k:g})"], rows, left=(0, 1)))
    if a["verdicts"]:
        page.source(campaign_path if by_kind else None)  # (the dispersion's; the modifications' are the result's)
        page.add(ui.table(["verdict"], [(v,) for v in a["verdicts"]], left=(0,)))
    else:
        page.add(ui.p("No thresholds given: --tolerance " + ",".join(f"{n}=…" for n in TOLERANCES)
                      + " (" + ", ".join(f"{n} in {u}" for n, u in TOLERANCES.items()) + ") adds a verdict line each.",
                      "note"))
    return a


class IdentifiedMachine:
    """The identified machine standing for the machine in a simulation (a report has no truth): the tool points
    of commands by the result's model (:meth:`~olti_drake.io.five_axis_io.Machine5Result.position_model`)."""

    def __init__(self, res):
        self.res, self.machine = res, res.machine

    def truth_positions(self, commands, directions=None, tool=None, frame: str = "workpiece") -> np.ndarray:
        return self.res.position_model(commands, directions, tool).positions(self.res.x)


#: The BK paths' rotary ranges tried, as shares of each axis' travel about 0, widest first.
BK_SHARES = (1.0, 0.75, 0.5, 0.25)


def bk_plan(machine):
    """(plan, ball mm, ranges deg): the widest BK-type paths (:func:`~olti_drake.model.five_axis_plan.bk_paths`)
    within the travel around a ball on the workpiece frame's z axis: the rotary ranges a share
    (:data:`BK_SHARES`) of each travel about 0, the ball's height over the nominal tool point's z span in 8 steps,
    first the widest ranges, then the lowest ball. A deterministic search; InputError when none fits."""
    from olti_drake.model.five_axis_plan import bk_paths

    rot = [machine.axes.index(a) for a in machine.rotary]
    ends = np.tile(((machine.lower + machine.upper) / 2), (2, 1))
    ends[:, rot] = np.clip(0.0, machine.lower[rot], machine.upper[rot])
    z = machine.axes.index("Z") if "Z" in machine.axes else None
    if z is not None:
        ends[:, z] = machine.lower[z], machine.upper[z]
    heights = np.linspace(*np.sort(machine.tool_points(ends)[:, 2]), 8)
    last = None
    for share in BK_SHARES:
        ranges = {a: (share * min(machine.lower[k], 0.0), share * max(machine.upper[k], 0.0))
                  for a, k in zip(machine.rotary, rot)}
        for h in heights:
            try:
                return bk_paths(machine, [0.0, 0.0, h], BK_STEPS, ranges_deg=ranges), np.array([0.0, 0.0, h]), ranges
            except InputError as e:
                last = e
    raise InputError(f"no BK-type paths within the travel around a ball on the workpiece z axis ({last})")


def _bk_section(page, res, k):
    """BK check paths: the hook to :func:`olti_drake.model.five_axis_compensation.bk_check` ("not computed" when
    it is not available or the paths leave the travel)."""
    page.add("<h2>BK check paths (ISO 10791-6)</h2>")
    try:
        from olti_drake.model.five_axis_compensation import bk_check, sequence_directions
    except ImportError as e:
        page.add(ui.p(f"not computed: the BK check is not available ({e}).", "note"))
        return None
    from olti_drake.model.propagation import predicted_std

    machine = res.machine
    try:
        plan, ball, ranges = bk_plan(machine)
        check = bk_check(IdentifiedMachine(res), plan, res.position_model, res.x)
    except InputError as e:
        page.add(ui.p(f"not computed: {e}", "note"))
        return None
    U = np.zeros(len(check.names))
    if res.covariance is not None:
        rot = [machine.axes.index(a) for a in machine.rotary]
        pm = res.position_model(plan.commands, sequence_directions(plan.commands[:, rot]), plan.tool)
        u = np.linalg.norm(predicted_std(pm.jacobian(res.x)[1].tocsr(), res.covariance, dim=3), axis=1)
        U = np.array([1e3 * k * u[plan.nest == j].max() for j in range(len(check.names))])
    page.add(ui.p(f"BK-type paths around a ball at ({', '.join(f'{v:.1f}' for v in ball)}) mm in the workpiece "
                  f"frame: each rotary axis alone through "
                  + ", ".join(f"{a} {lo:g}…{hi:g} deg" for a, (lo, hi) in ranges.items())
                  + f" and back ({BK_STEPS} poses each way), then all together, the linear axes keeping the "
                  f"nominal tool point on the ball. Simulated on the identified machine (the report has no truth): "
                  f"before compensation the deviation of its tool point from the ball, after compensation by this "
                  f"result what the inverse leaves; what a compensation can promise is bounded by U (k = {k:g}) of "
                  f"the predicted tool point along the path. µm."))
    rows = [(n, f"{a:.2f}", f"{b:.2f}", f"{c:.3f}", f"{d:.3f}", f"{e:.2f}") for n, a, b, c, d, e in
            zip(check.names, check.nominal_max_um, check.nominal_rms_um, check.compensated_max_um,
                check.compensated_rms_um, U)]
    page.add(ui.table(["path", "before: max", "before: RMS", "after: max", "after: RMS", f"U (k = {k:g}) max"], rows))
    return check


def _notes_section(page, raw):
    page.add("<h2>Notes, gauge and what was held</h2>")
    dropped = raw.get("dropped") or {}
    if dropped:
        page.add(ui.table(["held at 0", "why (not separable by the campaign)"], sorted(dropped.items()), left=(0, 1)))
    page.add(ui.p("Gauge: " + str(raw.get("gauge", "—"))))
    items = [("note", n) for n in raw.get("notes", [])] + [("warning", w) for w in raw.get("warnings", [])]
    if items:
        page.add(ui.table(["", "text"], items, left=(0, 1)))


def five_axis_page(raw, result_path, out_dir, unc_path=None, campaign_path=None, truth_path=None,
                   tolerances=None):
    """The filled :class:`~olti_drake.report.page.Page` of a five-axis result (module docstring); one-line errors for
    bad input before any figure is written."""
    from olti_drake.formats import UNCERTAINTY
    from olti_drake.io.csvio import read_json
    from olti_drake.io.five_axis_io import load_machine5_result, read_five_axis_campaign

    if truth_path:
        raise InputError(f"{os.fspath(truth_path)}: --truth does not apply to a five-axis result (its BK check paths "
                         f"are simulated on the identified machine)")
    tolerances = tolerances_of(tolerances)
    res = load_machine5_result(result_path)
    unc = read_json(unc_path, UNCERTAINTY, "an uncertainty file") if unc_path else None
    if unc is not None:
        check_uncertainty_file(unc, raw, unc_path, result_path)
    std = unc if unc is not None else raw["uncertainty"]
    k = float((unc or {}).get("expanded", {}).get("k", 2.0))
    fitted, note = None, ""
    if campaign_path:
        from olti_drake.estimation.five_axis_uncertainty import identification_at_result

        campaign = read_five_axis_campaign(campaign_path, res.machine)
        ident, fit, note = identification_at_result(res, campaign, result_path)
        fitted = (ident, fit)
    page = ui.Page(out_dir, result_path)
    _header(page, raw, result_path, unc, unc_path, campaign_path, note)
    _location_section(page, raw, std, k, unc_path)
    _motions_section(page, raw, std, k, unc_path)
    _linear_section(page, raw, k)
    by_kind = _residual_section(page, raw, fitted, campaign_path)
    _acceptance_section(page, raw, std, k, by_kind, tolerances, unc_path, campaign_path)
    _bk_section(page, res, k)
    _notes_section(page, raw)
    return page
