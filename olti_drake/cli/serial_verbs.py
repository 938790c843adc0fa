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
    root frame) per row with ``u_x_mm, u_y_mm, u_z_mm`` (k = 1, the result's covariance propagated); for a
    distance campaign also ``predicted_displacement_mm`` (cross-validation) and ``u_predicted_displacement_mm``.
    A result that stores no covariance (an older version's, a truth) gives no u columns, and says why."""
    import numpy as np

    from olti_drake.io.csvio import write_table
    from olti_drake.io.serial_io import header, load_serial_result, station_column

    res = load_serial_result(args.result, outside=args.outside)
    _, cols = header(args.commands)
    distance = "displacement_mm" in cols and ("station" in cols or "reflector" in cols)
    scol = station_column(args.commands) if distance else None
    jt = _commands(res, args.commands, (scol, "displacement_mm") if distance else (), (scol,) if distance else (),
                   valid_only=distance)
    from olti_drake.estimation.serial_uncertainty import predicted_point_std, predicted_reading_std

    p = _positions(res.model, jt, args.commands)
    _, u = predicted_point_std(res, jt.commands, jt.dirs)  # (None: the result stores no covariance)
    out, fmt = _joint_columns(jt)
    out.update({"x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2]})
    if u is not None:
        out.update({"u_x_mm": u[:, 0], "u_y_mm": u[:, 1], "u_z_mm": u[:, 2]})
    fmt.update({"x_mm": "%.6f", "y_mm": "%.6f", "z_mm": "%.6f", scol: "%d", "displacement_mm": "%.6f",
                "predicted_displacement_mm": "%.6f", "u_x_mm": "%.3e", "u_y_mm": "%.3e", "u_z_mm": "%.3e",
                "u_predicted_displacement_mm": "%.3e"})
    text = f"predicted {len(p)} tool points"
    if u is not None:
        un = np.linalg.norm(u, axis=1)
        text += f" (u (k = 1) of the point up to {1e3 * un.max():.2f} um, median {1e3 * np.median(un):.2f} um)"
    if distance:
        pred = _predicted_readings(res, jt, p, scol, args.commands)
        out = {scol: jt.table[scol], **out, "displacement_mm": jt.table["displacement_mm"],
               "predicted_displacement_mm": pred}
        if u is not None:
            out["u_predicted_displacement_mm"] = predicted_reading_std(res, jt.commands, jt.dirs, jt.table[scol],
                                                                       jt.table.get("time_s"))[1]
        miss = pred - jt.table["displacement_mm"]
        text += (f" and readings of {args.commands} ({jt.table['_skipped']} rows with valid = 0 skipped): "
                 f"predicted - read RMS {1e3 * np.sqrt(np.mean(miss ** 2)):.3f} um, "
                 f"max {1e3 * np.abs(miss).max():.3f} um")
        if u is not None:
            text += f", RMS of its u {1e3 * np.sqrt(np.mean(out['u_predicted_displacement_mm'] ** 2)):.3f} um"
    note = res.covariance_note
    comments = [f"olti predict: {args.result} applied to {args.commands}; tool point in the robot's root frame; "
                f"mm and degrees"]
    comments.append(f"u_*: standard uncertainties (k = 1) from the identification's covariance (linear propagation, "
                    f"JCGM 100) and its lack of fit {1e3 * res.lack_of_fit_mm:.3g} um in quadrature" if u is not None
                    else f"{note}: no u_* columns")
    write_table(args.out, out, fmt, comments=comments)
    print(text)
    if note:
        print(f"note: {note}: no u columns")
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


#: Exit status of ``olti compensate`` when some targets (not all) could not be compensated: the others are written.
EXIT_TARGETS_FAILED = 3


def compensate(args) -> int:
    """``olti compensate RESULT.json TARGETS.csv --out COMMANDS.csv [--tables DIR] [--urdf-out FILE]
    [--cartesian-out FILE] [--ros2-control-out FILE] [--ur-kinematics-out FILE] [--dh-out FILE]`` for a serial robot: targets x_mm, y_mm, z_mm with their
    nominal pose theta1_deg .. thetaN_deg (and dirs). Every target is solved; one that cannot be is a row with
    ``status`` != 0 (its nominal command kept), one line on stderr naming its file line, and exit
    :data:`EXIT_TARGETS_FAILED`; a program none of whose targets can be compensated is refused (exit 2, nothing
    written)."""
    import sys

    import numpy as np

    from olti_drake.estimation.compensation import compensation_table
    from olti_drake.estimation.serial_compensation import STATUS_LEGEND, STATUSES, solve_program
    from olti_drake.io.csvio import write_table
    from olti_drake.io.serial_io import load_serial_result

    res = load_serial_result(args.result, outside=args.outside)
    model = res.model
    cartesian_out = getattr(args, "cartesian_out", None)
    ros2_out = getattr(args, "ros2_control_out", None)
    ur_out = getattr(args, "ur_kinematics_out", None)
    dh_out = getattr(args, "dh_out", None)
    tables = [os.path.join(args.tables, f"{m.joint}_compensation.csv") for m in model.maps] if args.tables else []
    _preflight(args, [args.out, args.urdf_out, cartesian_out, ros2_out, ur_out, dh_out] + tables,
               [args.result, args.targets, res.robot_path], dirs=[args.tables] if args.tables else [])
    if args.tables and not model.maps:
        raise ValueError(f"{args.result}: --tables needs an error-map result (model 'errormap'), this one is "
                         f"'{model.kind}'")
    if ur_out:  # (refused before any work: a file that cannot be written is said first)
        from olti_drake.io.ur_kinematics import ur_segments

        ur_segments(model, res.robot_path)
    jt = _commands(res, args.targets, ("x_mm", "y_mm", "z_mm"))
    targets = np.column_stack([jt.table[c] for c in ("x_mm", "y_mm", "z_mm")])
    comp = solve_program(model, targets, jt.commands, jt.dirs, jt.line, args.targets)
    failed = comp.failures()
    if len(failed) == len(targets):
        raise ValueError(failed[0] + (f"; none of the {len(targets)} targets can be compensated (nothing written)"
                                      if len(targets) > 1 else ""))
    from olti_drake.io.serial_io import JointTable

    ok = comp.ok
    out, fmt = _joint_columns(JointTable(comp.commands, jt.dirs, jt.table, jt.source))
    out.update({"x_mm": targets[:, 0], "y_mm": targets[:, 1], "z_mm": targets[:, 2],
                "residual_mm": comp.residual_mm, "orientation_change_deg": comp.orientation_change_deg,
                "status": comp.status_codes})
    fmt.update({"x_mm": "%.6f", "y_mm": "%.6f", "z_mm": "%.6f", "residual_mm": "%.3g",
                "orientation_change_deg": "%.3g", "status": "%d"})
    write_table(args.out, out, fmt, comments=[
        f"olti compensate: {args.result} inverted for the targets of {args.targets}; mm and degrees",
        "executed with these directions the commands put the tool point on x_mm, y_mm, z_mm by the model; "
        "residual_mm: how far by the model; orientation_change_deg: tool orientation off the nominal pose's",
        f"status: {STATUS_LEGEND}; a row whose status is not 0 keeps its nominal command, uncompensated (stderr "
        f"says why, by line)"])
    corr = np.abs(comp.correction_deg[ok])
    print(f"compensated {int(ok.sum())} of {len(targets)} targets ({model.kind} model of "
          f"{res.data['robot']['file']}): {comp.iterations} Newton iteration(s), max residual "
          f"{comp.residual_mm[ok].max():.2g} mm, corrections up to {1e3 * corr.max():.2f} mdeg, tool orientation "
          f"kept within {comp.orientation_change_deg[ok].max():.2g} deg")
    print(f"wrote {args.out}")
    if cartesian_out:
        _write_cartesian(cartesian_out, model, comp, targets, args)
        print(f"wrote {cartesian_out} (pre-distorted Cartesian targets for the controller's nominal IK)")
    if ros2_out:
        from olti_drake.io.ros2_control import write_ros2_control_offsets

        offsets = write_ros2_control_offsets(model, ros2_out, res.data["robot"]["file"], args.result)
        print(f"wrote {ros2_out} (ros2_control joint offsets, radians: "
              f"{', '.join(f'{j} {v:.3g}' for j, v in offsets.items())})")
    if ur_out:
        from olti_drake.io.ur_kinematics import write_ur_kinematics

        rep = write_ur_kinematics(model, res.robot_path, ur_out, res.data["robot"]["file"], args.result)
        print(f"wrote {ur_out} (UR-style kinematics, hash {rep.hash}; tool point residual vs the model RMS "
              f"{1e3 * rep.residual_rms_mm:.3g} um, max {1e3 * rep.residual_max_mm:.3g} um"
              + (f"; not held: {'; '.join(rep.cannot_hold)}" if rep.cannot_hold else "") + ")")
    if dh_out:
        from olti_drake.io.dh_table import write_dh_table

        rep = write_dh_table(model, dh_out, res.data["robot"]["file"], args.result)
        print(f"wrote {dh_out} (D-H table" + (f", Hayati's beta for {', '.join(rep['hayati'])}" if rep["hayati"]
                                              else "") +
              f"; tool point residual vs the model RMS {1e3 * rep['residual_rms_mm']:.3g} um, max "
              f"{1e3 * rep['residual_max_mm']:.3g} um; not held: {'; '.join(rep['cannot_hold'])})")
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
    for reason, status in zip(comp.reasons, comp.status):
        if status != "ok":
            print(f"{reason} (status {STATUSES.index(status)} {status}: the row keeps its nominal command)",
                  file=sys.stderr)
    if failed:
        print(f"{len(failed)} of {len(targets)} targets not compensated (status column of {args.out}); the "
              f"others are written", file=sys.stderr)
        return EXIT_TARGETS_FAILED
    return 0


def _write_cartesian(path, model, comp, targets, args) -> None:
    """The pre-distorted Cartesian targets (``--cartesian-out``): the nominal model's tool point and tool-frame
    orientation at every row's command (:func:`olti_drake.estimation.serial_compensation.cartesian_targets`)."""
    import numpy as np

    from olti_drake.estimation.serial_compensation import STATUS_LEGEND, cartesian_targets, rotation_angles
    from olti_drake.io.csvio import write_table

    p, rot = cartesian_targets(model, comp.commands)
    rpy, quat = rotation_angles(rot)
    tool = model.chain_parameters(model.start_vector())[6 * model.chain.n_joints:]
    cols = {"x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "rx_deg": rpy[:, 0], "ry_deg": rpy[:, 1],
            "rz_deg": rpy[:, 2], "qw": quat[:, 0], "qx": quat[:, 1], "qy": quat[:, 2], "qz": quat[:, 3],
            "wanted_x_mm": targets[:, 0], "wanted_y_mm": targets[:, 1], "wanted_z_mm": targets[:, 2],
            "shift_mm": np.linalg.norm(p - targets, axis=1), "status": comp.status_codes}
    fmt = {c: "%.6f" for c in cols}
    fmt.update({c: "%.12f" for c in ("rx_deg", "ry_deg", "rz_deg", "qw", "qx", "qy", "qz")})
    fmt.update({"shift_mm": "%.4g", "status": "%d"})
    write_table(path, cols, fmt, comments=[
        f"olti compensate --cartesian-out: pre-distorted Cartesian targets of {args.targets} by {args.result}; mm "
        f"and degrees, root frame of {model.chain.path}",
        f"x_mm, y_mm, z_mm: the TCP = the tool point, ({', '.join(f'{v:.6g}' for v in tool)}) mm in tool frame "
        f"'{model.chain.tool_frame}', by the NOMINAL model (the model file: the controller's own kinematics) at "
        f"the compensated command; send it with this orientation to the controller's IK (TCP set to that offset)",
        "rx_deg, ry_deg, rz_deg: the tool frame's orientation, fixed-axis X-Y-Z roll-pitch-yaw, R = Rz(rz) Ry(ry) "
        "Rx(rx); qw, qx, qy, qz: the same rotation as a unit quaternion (qw >= 0)",
        "the IK solution on the nominal pose's branch is the compensated command, which puts the real robot's tool "
        "point on wanted_x_mm, wanted_y_mm, wanted_z_mm (shift_mm: how far the target was moved); a row whose "
        f"status is not 0 is the nominal command's pose, uncompensated (status: {STATUS_LEGEND})"])
