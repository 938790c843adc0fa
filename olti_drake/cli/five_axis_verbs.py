"""``olti identify --machine`` (its summary) and ``olti predict`` of a five-axis machine result (``olti-machine5/1``;
formats.md, "Five-axis machine tools"; docs/five_axis.md). Units: mm, deg, µrad."""

import numpy as np


def summary(ident, fit, doc) -> str:
    """A few lines: readings, residual RMS (µm), every identified location error with its u (k = 1), what is held,
    the fit's warnings and suspect readings (by file line)."""
    from olti_drake.estimation.calibration import suspect_readings_line

    lines = [f"five-axis machine {doc['machine']['file']} ({', '.join(doc['machine']['axes'])}), model "
             f"{doc['model']}: {doc['n_readings']} readings, residual RMS {1e3 * doc['residual_rms_mm']:.3f} um",
             "location errors (u, k = 1):"]
    unc = doc["uncertainty"]["location_errors"]
    for name, v in doc["location_errors"].items():
        if name in doc.get("held", ()):
            continue
        unit = "um" if name.endswith("_mm") else "urad"
        scale = 1e3 if unit == "um" else 1.0
        lines.append(f"  {name:<12} {scale * v:10.3f} {unit} +- {scale * unc[name]:.3f}")
    if doc.get("held"):
        lines.append(f"held at 0 (not separable, see notes): {', '.join(doc['held'])}")
    if doc.get("error_motions"):
        lines.append(f"error motions: {', '.join(doc['error_motions'])} on their grids")
    lines.append(_linear_line(doc))
    lines += [f"  warning: {w}" for w in doc.get("warnings", ())]
    lines += [t for t in [suspect_readings_line(doc.get("outliers"))] if t]
    return "\n".join(lines)


def _linear_line(doc) -> str:
    """How the result has the linear axes: identified (knots, the largest motion and its u), fixed or perfect."""
    if doc.get("linear_from"):
        return f"linear axes: held fixed from {doc['linear_from'].get('file')}"
    lin = doc.get("linear")
    if not lin:  # (the program's note says whether --linear perfect or auto chose it, and why)
        said = [n for n in doc.get("notes", []) if n.startswith("linear axes:")]
        return said[0] if said else "linear axes: taken as perfect"
    unc = doc["uncertainty"]["linear"]["error_motions"]
    worst = max(lin["error_motions"], key=lambda n: np.max(np.abs(lin["error_motions"][n]["values"]), initial=0.0))
    v, u = np.asarray(lin["error_motions"][worst]["values"]), np.asarray(unc[worst]["values"])
    i, e = int(np.argmax(np.abs(v))), lin["error_motions"][worst]
    return (f"linear axes: 18 error motions and 3 squareness errors identified (B-spline knots every "
            f"{doc['error_model']['knot_spacing_mm']:g} mm); largest {worst} {v[i]:.4g} {e['unit']} +- {u[i]:.2g} "
            f"at {e['axis']} = {e['positions_mm'][i]:g} mm")


def predict(args) -> int:
    """``olti predict R.json POINTS.csv --out P.csv``: the tool point in the workpiece frame (mm) of every command
    by the identified machine, and its standard uncertainty (k = 1), sqrt(diag(J C Jᵀ))
    (:func:`olti_drake.model.propagation.predicted_std`; 0 when the result stores no covariance) with the
    result's lack of fit (``covariance.lack_of_fit_mm``) in quadrature."""
    from olti_drake.io.five_axis_io import load_machine5_result, read_five_axis_points, write_predictions
    from olti_drake.model.propagation import with_lack_of_fit
    from olti_drake.model.propagation import predicted_std

    res = load_machine5_result(args.result)
    c, d, tool, _ = read_five_axis_points(args.commands, res.machine)
    if res.errors.bidirectional and res.errors.maps and d is None:
        d = np.ones((len(c), len(res.machine.rotary)))
        print("note: the points carry no approach directions: +1 (forward branch of the maps) taken")
    pm = res.position_model(c, d, tool)
    p, J = pm.jacobian(res.x)
    u = (predicted_std(J.tocsr(), res.covariance, dim=3) if res.covariance is not None else np.zeros_like(p))
    u = with_lack_of_fit(u, res.lack_of_fit_mm)  # (the maps' representation on their grid: estimation.five_axis)
    write_predictions(args.out, c, d, tool, res.machine, p, u)
    print(f"predicted {len(c)} tool points (five-axis machine, workpiece frame); max u (k=1) {1e3 * u.max():.2f} um; "
          f"wrote {args.out}")
    return 0


#: ``--cnc`` names (cli.md) of the exporters of :mod:`olti_drake.io.cnc` where they differ: the one place.
CNC_FORMATS = {"siemens": "sinumerik"}
#: The tool direction columns of a five-axis targets file (a unit vector is not required: normalized).
DIRECTION_COLUMNS = ("i", "j", "k")


def read_targets(path, machine):
    """(points (M, 3) mm, tool directions (M, 3) or None, nominal rotary commands (M, n_rotary) deg or None,
    approach directions (M, n_rotary) or None, tool (M,), file lines) of a five-axis TARGETS.csv: ``x_mm, y_mm,
    z_mm`` (workpiece frame), the tool direction ``i, j, k`` (workpiece frame, from the tool point into the
    spindle) and/or the nominal pose ``<letter>_cmd_deg`` of every rotary axis (one of the two), optional
    ``dir_<letter>`` and ``tool``. One-line InputError naming the file and line otherwise."""
    import os

    from olti_drake.errors import InputError
    from olti_drake.io.csvio import check_finite, read_table
    from olti_drake.io.serial_io import header

    name = os.fspath(path)
    hline, cols = header(path)
    rot_cmd = [f"{a.lower()}_cmd_deg" for a in machine.rotary]
    dirs = [f"dir_{a.lower()}" for a in machine.rotary]
    for group in (DIRECTION_COLUMNS, rot_cmd, dirs):
        some = [c for c in group if c in cols]
        if some and len(some) != len(group):
            raise InputError(f"{name}:{hline}: missing column '{next(c for c in group if c not in cols)}' (with "
                             f"'{some[0]}': give all of {', '.join(group)} or none)")
    for a in set("ABC") - set(machine.rotary):
        for c in (f"{a.lower()}_cmd_deg", f"dir_{a.lower()}"):
            if c in cols:
                raise InputError(f"{name}:{hline}: column '{c}' is for axis {a}, which machine model {machine.path} "
                                 f"does not have (its axes: {', '.join(machine.axes)})")
    if not any(c in cols for c in DIRECTION_COLUMNS + tuple(rot_cmd)):
        raise InputError(f"{name}:{hline}: no tool direction: give the columns i, j, k (the tool axis in the "
                         f"workpiece frame) or the nominal pose {', '.join(rot_cmd)} (its orientation kept)")
    t = read_table(path, ("x_mm", "y_mm", "z_mm"), DIRECTION_COLUMNS + tuple(rot_cmd) + tuple(dirs) + ("tool",),
                   integer=tuple(dirs) + ("tool",))
    check_finite(t, path, [c for c in ("x_mm", "y_mm", "z_mm", *DIRECTION_COLUMNS, *rot_cmd) if c in t])
    for c in dirs if dirs[0] in t else ():
        bad = np.flatnonzero(~np.isin(t[c], (-1.0, 1.0)))
        if bad.size:
            raise InputError(f"{name}:{t['_line'][bad[0]]}: column '{c}': {t[c][bad[0]]:g} is not +1 or -1")
    tool = t["tool"].astype(int) if "tool" in t else np.zeros(len(t["_line"]), int)

    def stack(names):
        return np.column_stack([t[c] for c in names]) if names[0] in t else None
    return (stack(("x_mm", "y_mm", "z_mm")), stack(DIRECTION_COLUMNS), stack(rot_cmd), stack(dirs), tool,
            t["_line"])


#: What ``--tables DIR`` alone writes on a five-axis result: the error-map tables of every kind's ``--tables``,
#: here every identified value by ISO name, each error-motion node with its grid angle (``--cnc csv``; mm, µrad).
TABLES_FORMAT = "csv"


def export_files(args, machine):
    """(format, the files it writes in ``--tables DIR``, their directories) of ``olti compensate`` on a five-axis
    result: ``--cnc FORMAT`` (:data:`CNC_FORMATS`), or :data:`TABLES_FORMAT` with ``--tables`` alone; (None, [],
    []) without ``--tables``. The names are the exporter's own (:func:`olti_drake.io.cnc.cnc_file_names`), so
    that each is checked before any work."""
    import os

    from olti_drake.io.cnc import cnc_file_names

    if not args.tables:
        return None, [], []
    fmt = CNC_FORMATS.get(args.cnc, args.cnc) if args.cnc else TABLES_FORMAT
    files = [os.path.join(args.tables, *name.split("/")) for name in cnc_file_names(fmt, machine)]
    return fmt, files, list(dict.fromkeys([args.tables] + [os.path.dirname(f) for f in files]))


def compensate(args) -> int:
    """``olti compensate R.json TARGETS.csv --out COMMANDS.csv [--tables DIR [--cnc FORMAT]]`` on a five-axis
    result: the X, Y, Z and rotary commands that put the tool point on every target with its tool direction by
    the identified model (:func:`olti_drake.model.five_axis_compensation.compensate`); ``--tables DIR``: the
    identified model's files (:func:`olti_drake.io.cnc.export`) with what they cannot hold and their residual,
    in the format ``--cnc`` names (the controller's) or, alone, the error-map tables ``identified.csv``
    (:data:`TABLES_FORMAT`). Every output, each of those files by name, is checked before any work: an existing
    one is replaced only with ``--force``."""
    from olti_drake.cli.volumetric_verbs import _preflight
    from olti_drake.io.five_axis_io import load_machine5_result
    from olti_drake.model.five_axis_compensation import compensate as invert

    if args.outside == "clamp":
        raise ValueError("--outside clamp: a five-axis compensation refuses targets outside the travel (the error "
                         "motions are identified within it)")
    if args.cnc and not args.tables:
        raise ValueError(f"--cnc {args.cnc} needs --tables DIR (the directory its files are written to)")
    res = load_machine5_result(args.result)  # (first: the files a format writes depend on the machine's axes)
    m = res.machine
    fmt, files, out_dirs = export_files(args, m)
    _preflight(args, [args.out] + files, [args.result, args.targets], dirs=out_dirs)
    pts, dirs, rot, approach, tool, lines = read_targets(args.targets, m)
    comp = invert(res.position_model, res.x, m, pts, dirs, rot, tool, approach, lines, str(args.targets))
    report = _export(args, fmt, out_dirs, res, comp, tool) if fmt else None  # (first: a refusal leaves nothing)
    _write_commands(args, m, comp, tool)
    k = [m.axes.index(a) for a in m.rotary]
    step = np.abs(comp.commands - comp.nominal)
    print(f"compensated {len(pts)} targets (five-axis TCP, workpiece frame): max correction "
          f"{1e3 * step[:, [m.axes.index(a) for a in m.linear]].max():.2f} um, "
          f"{1e3 * step[:, k].max():.3f} mdeg; max residual {comp.position_residual_mm.max():.2g} mm, tool direction "
          f"{1e6 * comp.direction_residual_rad.max():.3g} urad; wrote {args.out}")
    far = np.flatnonzero(comp.direction_residual_rad > 1e-6)
    if far.size:
        print(f"note: {far.size} target(s) near the singular tool direction (along a rotary axis line), e.g. line "
              f"{lines[far[0]]}: the exact direction would need a large rotary move; the tool point is exact, the "
              f"direction within {1e6 * comp.direction_residual_rad.max():.3g} urad")
    if report is not None:
        print(report.describe())
    return 0


def _export(args, fmt, out_dirs, res, comp, tool):
    """:func:`olti_drake.io.cnc.export` of the identified model into ``--tables DIR`` (its ExportReport). Run
    before COMMANDS.csv is written: a format that refuses the machine or a value (one line, before it writes its
    files: the LinuxCNC module's table A on table C, FANUC's field) leaves nothing, not even the directories
    ``out_dirs`` (:func:`export_files`) it made."""
    import os

    from olti_drake.io.cnc import export

    made = set()
    for d in out_dirs:  # (with their parents that do not exist yet)
        d = os.path.abspath(d)
        while not os.path.exists(d):
            made.add(d)
            d = os.path.dirname(d)
    try:
        return export(fmt, res.machine, res.errors, res.position_model(
            comp.commands[:1], None if comp.directions is None else comp.directions[:1], tool[:1]).theta(res.x),
            args.tables)
    except Exception:
        for d in sorted(made, key=len, reverse=True):  # (only what this run made, and only when empty)
            try:
                os.rmdir(d)
            except OSError:
                pass
        raise


def _write_commands(args, machine, comp, tool) -> None:
    """COMMANDS.csv: the command columns of formats.md's five-axis campaign, the approach directions used, ``tool``,
    then the wanted point and tool direction repeated."""
    from olti_drake.io.csvio import write_table
    from olti_drake.io.five_axis_io import command_columns

    cols = {c: comp.commands[:, k] for k, c in enumerate(command_columns(machine.axes))}
    fmt = {c: "%.6f" for c in cols}
    for k, a in enumerate(machine.rotary if comp.directions is not None else ()):
        cols[f"dir_{a.lower()}"], fmt[f"dir_{a.lower()}"] = comp.directions[:, k], "%d"
    cols["tool"], fmt["tool"] = tool, "%d"
    for k, c in enumerate(("x_mm", "y_mm", "z_mm") + DIRECTION_COLUMNS):
        cols[c] = (comp.points_mm if k < 3 else comp.tool_dirs)[:, k % 3]
        fmt[c] = "%.6f" if k < 3 else "%.9f"
    write_table(args.out, cols, fmt, comments=[
        f"olti compensate: {args.result} inverted for the targets of {args.targets}; mm, deg",
        "x_cmd_mm .. <letter>_cmd_deg put tool 'tool' on x_mm, y_mm, z_mm with the tool direction i, j, k (unit, "
        "workpiece frame, from the tool point into the spindle) by the identified five-axis model; dir_<letter>: "
        "the approach directions the compensation used (formats.md)"])
