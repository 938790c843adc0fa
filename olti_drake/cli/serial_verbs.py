"""The ``olti`` verbs for N-joint serial robots (``--robot FILE|ur5|scara``): predict, compensate.

Dispatched from :mod:`olti_drake.cli.verbs` when the result is a serial robot's (its kind,
:mod:`olti_drake.cli.kinds`); ``olti identify --robot`` is the one identify route
(:mod:`olti_drake.cli.identify`). Parsing and printing only; the work is in
:mod:`olti_drake.estimation.serial_compensation` and :mod:`olti_drake.io.serial_io`. Units: mm and degrees.
"""

import os

def _preflight(args, files, inputs, dirs=()):
    from olti_drake.io.outputs import preflight

    preflight(files, inputs, force=getattr(args, "force", False), dirs=dirs, create_dirs=bool(dirs))


def _commands(res, path, required=(), integer=(), valid_only=False):
    """The joint table of a commands / targets / campaign file for a loaded result, with directions when
    the result's maps need them."""
    from olti_drake.io.serial_io import read_joint_table

    model = res.model
    jt = read_joint_table(path, model.chain.n_joints, required, ("time_s",), integer=integer,
                          robot=res.data["robot"]["file"], valid_only=valid_only)
    if jt.dirs is None and model.bidirectional:
        raise ValueError(f"{path}: no direction columns, but the error maps of {res.data['robot']['file']} in the "
                         f"result are bidirectional: add dir1 .. dir{model.chain.n_joints} (+1/-1)")
    return jt


def _positions(model, jt, path, outside_hint=True):
    """Tool points (M, 3) mm of a joint table by the model; a command outside a map grid names its line."""
    from olti_drake.model.errormap import OutsideGridError

    try:
        return model.positions(jt.commands, jt.dirs)
    except OutsideGridError as e:
        raise ValueError(f"{path}:{jt.line[e.row]}: {e}" + (" -- or run with --outside clamp" if outside_hint
                                                           else "")) from None


def _joint_columns(jt) -> tuple:
    """(columns, formats) repeating a table's joint and direction columns."""
    from olti_drake.io.serial_io import dir_columns, theta_columns

    n = jt.n_joints
    cols = {c: jt.commands[:, i] for i, c in enumerate(theta_columns(n))}
    if jt.dirs is not None:
        cols.update({c: jt.dirs[:, i] for i, c in enumerate(dir_columns(n))})
    return cols, {**{c: "%.12g" for c in theta_columns(n)}, **{c: "%d" for c in dir_columns(n)}}


def predict(args) -> int:
    """``olti predict RESULT.json FILE.csv --out PRED.csv`` for a serial robot: the tool point (x, y, z mm,
    root frame) per row; for a distance campaign also ``predicted_displacement_mm`` (cross-validation)."""
    import numpy as np

    from olti_drake.io.csvio import write_table
    from olti_drake.io.serial_io import header, load_serial_result, station_column

    res = load_serial_result(args.result, outside=args.outside)
    _, cols = header(args.commands)
    distance = "displacement_mm" in cols and ("station" in cols or "reflector" in cols)
    scol = station_column(args.commands) if distance else None
    jt = _commands(res, args.commands, (scol, "displacement_mm") if distance else (), (scol,) if distance else (),
                   valid_only=distance)
    p = _positions(res.model, jt, args.commands)
    out, fmt = _joint_columns(jt)
    out.update({"x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2]})
    fmt.update({"x_mm": "%.6f", "y_mm": "%.6f", "z_mm": "%.6f", scol: "%d", "displacement_mm": "%.6f",
                "predicted_displacement_mm": "%.6f"})
    text = f"predicted {len(p)} tool points"
    if distance:
        pred = _predicted_readings(res, jt, p, scol, args.commands)
        out = {scol: jt.table[scol], **out, "displacement_mm": jt.table["displacement_mm"],
               "predicted_displacement_mm": pred}
        miss = pred - jt.table["displacement_mm"]
        text += (f" and readings of {args.commands} ({jt.table['_skipped']} rows with valid = 0 skipped): "
                 f"predicted - read RMS {1e3 * np.sqrt(np.mean(miss ** 2)):.3f} um, "
                 f"max {1e3 * np.abs(miss).max():.3f} um")
    write_table(args.out, out, fmt, comments=[f"olti predict: {args.result} applied to {args.commands}; "
                                              f"tool point in the robot's root frame; mm and degrees"])
    print(text)
    print(f"wrote {args.out}")
    return 0


def _predicted_readings(res, jt, p, scol, path):
    """‖p − P_j‖ − d0_j of every row by the result's stations (000 Eq. (10) in 3D), mm."""
    import numpy as np

    if res.stations_mm is None:
        raise ValueError(f"{path}: a distance campaign, but the result has no stations (identified from tracker "
                         f"points): predicted_displacement_mm needs a distance result")
    labels = res.station_labels
    station = jt.table[scol].astype(int)
    known = np.isin(station, labels)
    if not known.all():
        k = np.flatnonzero(~known)[0]
        raise ValueError(f"{path}:{jt.line[k]}: column '{scol}': station {station[k]} is not one the result "
                         f"identified ({', '.join(str(j) for j in labels)})")
    idx = np.searchsorted(labels, station) if np.all(np.diff(labels) > 0) else np.array(
        [list(labels).index(j) for j in station])
    d0 = res.dead_paths_mm[idx]
    if "drift_mm_per_h" in res.data:  # --drift: d0_j(t) = d0_j + v_j (t - t_ref_j); without times, at t_ref_j
        if "time_s" not in jt.table:
            raise ValueError(f"{path}: the result has a dead-path drift (--drift): predicted_displacement_mm needs "
                             f"the 'time_s' column of every reading")
        v = np.asarray(res.data["drift_mm_per_h"], float)[idx]
        ref = np.asarray(res.data["drift_reference_h"], float)[idx]
        d0 = d0 + v * (jt.table["time_s"] / 3600.0 - ref)
    return np.linalg.norm(p - res.stations_mm[idx], axis=1) - d0


def compensate(args) -> int:
    """``olti compensate RESULT.json TARGETS.csv --out COMMANDS.csv [--tables DIR] [--urdf-out FILE]`` for a
    serial robot: targets x_mm, y_mm, z_mm with their nominal pose theta1_deg .. thetaN_deg (and dirs)."""
    import numpy as np

    from olti_drake.estimation.compensation import compensation_table
    from olti_drake.estimation.serial_compensation import compensate_serial
    from olti_drake.io.csvio import write_table
    from olti_drake.io.serial_io import load_serial_result

    res = load_serial_result(args.result, outside=args.outside)
    model = res.model
    tables = [os.path.join(args.tables, f"{m.joint}_compensation.csv") for m in model.maps] if args.tables else []
    _preflight(args, [args.out, args.urdf_out] + tables,
               [args.result, args.targets, res.robot_path], dirs=[args.tables] if args.tables else [])
    if args.tables and not model.maps:
        raise ValueError(f"{args.result}: --tables needs an error-map result (model 'errormap'), this one is "
                         f"'{model.kind}'")
    jt = _commands(res, args.targets, ("x_mm", "y_mm", "z_mm"))
    targets = np.column_stack([jt.table[c] for c in ("x_mm", "y_mm", "z_mm")])
    comp = compensate_serial(model, targets, jt.commands, jt.dirs, jt.line, args.targets)
    from olti_drake.io.serial_io import JointTable

    out, fmt = _joint_columns(JointTable(comp.commands, jt.dirs, jt.table, jt.source))
    out.update({"x_mm": targets[:, 0], "y_mm": targets[:, 1], "z_mm": targets[:, 2],
                "residual_mm": comp.residual_mm, "orientation_change_deg": comp.orientation_change_deg})
    fmt.update({"x_mm": "%.6f", "y_mm": "%.6f", "z_mm": "%.6f", "residual_mm": "%.3g",
                "orientation_change_deg": "%.3g"})
    write_table(args.out, out, fmt, comments=[
        f"olti compensate: {args.result} inverted for the targets of {args.targets}; mm and degrees",
        "executed with these directions the commands put the tool point on x_mm, y_mm, z_mm by the model; "
        "residual_mm: how far by the model; orientation_change_deg: tool orientation off the nominal pose's"])
    corr = np.abs(comp.correction_deg)
    print(f"compensated {len(targets)} targets ({model.kind} model of {res.data['robot']['file']}): "
          f"{comp.iterations} Newton iteration(s), max residual {comp.residual_mm.max():.2g} mm, corrections up to "
          f"{1e3 * corr.max():.2f} mdeg, tool orientation kept within {comp.orientation_change_deg.max():.2g} deg")
    print(f"wrote {args.out}")
    if tables:
        from olti_drake.io.outputs import make_dir

        make_dir(args.tables)
    for m, path in zip(model.maps, tables):
        write_table(path, compensation_table(m.emap), {}, comments=[
            f"olti compensate: bidirectional compensation table of {m.joint} from {args.result}; degrees",
            "angle_deg: wanted actual angle (map node); forward/reverse_command_deg: the command to send when "
            "approaching in +1/-1 (000 Eq. 7 inverted)"])
        print(f"wrote {path}")
    if args.urdf_out:
        from olti_drake.io.identified_urdf import write_identified_urdf

        point = write_identified_urdf(model, res.robot_path, args.urdf_out, f"Result: {args.result}.")
        print(f"wrote {args.urdf_out} (identified joint origins; tool point = link '{point}')")
    return 0
