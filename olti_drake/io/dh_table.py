"""The identified geometry as a Denavit-Hartenberg table (``olti compensate --dh-out F.csv``; issue 26, item 3).

Convention: **standard (distal) D-H**, one row per fixed base step and per joint, chain order; row k maps frame
k-1 to frame k by

    T_k = Rz(θ_k + theta_offset_deg) · Tz(d_mm) · Tx(a_mm) · Rx(alpha_deg) · Ry(beta_deg)

with θ_k the joint's command (deg; 0 for the ``base`` row, the fixed step from the model's root frame to frame 0,
whose z is joint 1's axis). Frame k's z is joint k+1's axis; the last joint's row ends at the tool point, the
origin of frame N (a, d: its radius and height about the last axis). ``beta_deg`` is 0 on every classic row. Where
two consecutive axes are within :data:`PARALLEL_DEG` of parallel, classic D-H is ill-conditioned (the common
normal's foot d runs to infinity as the angle goes to 0): that row is **Hayati's** modification instead (d_mm = 0,
the rotation about y beta_deg), stated in the file by joint pair. Joint angles' identified offsets (``dh``) or the
error maps' level (``errormap``, :func:`olti_drake.io.ros2_control.joint_offsets`) are in theta_offset_deg.

What a D-H table cannot hold: the error maps' command- and direction-dependent part, the joint compliance, and the
tool frame's orientation (the identification has a tool point, not a flange frame). :func:`write_dh_table` states
them and the residual they leave (RMS and max mm of the tool point, the table's forward kinematics
:func:`dh_positions` vs the identified model on :data:`RESIDUAL_POSES` seeded random poses within the identified
ranges, :func:`olti_drake.io.ur_kinematics._ranges`)."""

from __future__ import annotations

import numpy as np

from olti_drake.errors import InputError

#: Consecutive axes closer to parallel than this (deg) get Hayati's row (d = 0, beta) instead of classic D-H.
PARALLEL_DEG = 10.0
COLUMNS = ("joint", "a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg")
#: The name of the fixed first row (root frame -> frame 0).
BASE = "base"
RESIDUAL_POSES = 10_000


def _rot(axis: int, deg) -> np.ndarray:
    """(M, 3, 3) rotations about x, y or z (axis 0, 1, 2) by ``deg`` (M,)."""
    t = np.radians(np.atleast_1d(np.asarray(deg, float)))
    c, s = np.cos(t), np.sin(t)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    r = np.zeros((len(t), 3, 3))
    r[:, axis, axis] = 1.0
    r[:, i, i], r[:, j, j], r[:, i, j], r[:, j, i] = c, c, -s, s
    return r


def zero_lines(model):
    """The identified model at command 0 (with its offsets / map levels): ([(point, unit direction)] of every joint
    axis, chain order, and the tool point), mm in the root frame: the chain model of
    :mod:`olti_drake.model.chain`, frame by frame."""
    from olti_drake.io.ros2_control import joint_offsets
    from olti_drake.model.chain import _axis_rotation

    chain = model.chain
    params = model.chain_parameters(model.start_vector())
    levels = joint_offsets(model)
    rot, org, lines = np.eye(3), np.zeros(3), []
    for i, name in enumerate(chain.joint_names):
        fixed, g = chain.fixed_mm[i], params[6 * i:6 * i + 6]
        rot_g = rot @ fixed[:3, :3]
        org = org + rot @ fixed[:3, 3] + rot_g @ g[:3]
        rot = rot_g @ _rot(0, g[3])[0] @ _rot(1, g[4])[0] @ _rot(2, g[5])[0]
        axis = rot @ chain.axes[i]
        lines.append((org.copy(), axis / np.linalg.norm(axis)))
        rot = rot @ _axis_rotation(chain.axes[i], np.radians(levels[name][0]))
    tool = chain.fixed_mm[chain.n_joints]
    return lines, org + rot @ tool[:3, 3] + rot @ tool[:3, :3] @ params[-3:]


def _step(frame, point, direction):
    """One row (theta_deg, d, a, alpha_deg, beta_deg, hayati) from ``frame`` (4x4, z along the row's rotation axis)
    to the next frame, z along the line (``point``, ``direction``), origin on it; ``direction`` None: the
    frame's origin is ``point`` (the tool point's row)."""
    r, o = frame[:3, :3], frame[:3, 3]
    z = r[:, 2]
    local = r.T @ (point - o)
    hayati = direction is not None and np.degrees(np.arccos(min(1.0, abs(z @ direction)))) < PARALLEL_DEG
    if direction is None or hayati:  # origin where the line meets the plane z = 0 of the frame (d = 0)
        if hayati:
            u = r.T @ direction
            local = local - u * local[2] / u[2]
        d = 0.0 if hayati else local[2]
        theta = np.degrees(np.arctan2(local[1], local[0])) if np.hypot(local[0], local[1]) > 1e-12 else 0.0
        a = float(np.hypot(local[0], local[1]))
        if not hayati:
            return theta, d, a, 0.0, 0.0, False
        u = _rot(2, -theta)[0] @ u  # the direction in the turned frame: Rx(alpha) Ry(beta) e_z
        return theta, 0.0, a, np.degrees(np.arctan2(-u[1], u[2])), np.degrees(np.arcsin(np.clip(u[0], -1, 1))), True
    u = r.T @ direction
    normal = np.cross([0.0, 0.0, 1.0], u)
    normal /= np.linalg.norm(normal)
    # feet of the common normal: z line (0, 0, s) and the next line local + t u
    s, t = np.linalg.lstsq(np.column_stack([[0.0, 0.0, 1.0], -u]), local, rcond=None)[0]
    foot = local + t * u
    a = float(normal @ (foot - np.array([0.0, 0.0, s])))
    theta = np.degrees(np.arctan2(normal[1], normal[0]))
    x_turned = _rot(2, -theta)[0] @ u
    return theta, s, a, np.degrees(np.arctan2(-x_turned[1], x_turned[2])), 0.0, False


def row_transform(theta_deg, d, a, alpha_deg, beta_deg) -> np.ndarray:
    """(M, 4, 4) T = Rz(θ) Tz(d) Tx(a) Rx(α) Ry(β) (module docstring) for θ (M,) deg."""
    th = np.atleast_1d(np.asarray(theta_deg, float))
    t = np.zeros((len(th), 4, 4))
    rz = _rot(2, th)
    t[:, :3, :3] = rz @ _rot(0, alpha_deg)[0] @ _rot(1, beta_deg)[0]
    t[:, :3, 3] = rz @ np.array([a, 0.0, 0.0]) + np.array([0.0, 0.0, d])
    t[:, 3, 3] = 1.0
    return t


def dh_rows(model) -> list:
    """[(joint name or ``base``, a, alpha, d, theta_offset, beta, hayati)] of ``model`` (module docstring)."""
    lines, tool = zero_lines(model)
    frame, rows = np.eye(4), []
    names = (BASE,) + tuple(model.chain.joint_names)
    targets = lines + [(tool, None)]
    for name, (point, direction) in zip(names, targets):
        theta, d, a, alpha, beta, hayati = _step(frame, point, direction)
        rows.append((name, a, alpha, d, theta, beta, hayati))
        frame = frame @ row_transform(theta, d, a, alpha, beta)[0]
    return rows


def dh_positions(rows, commands_deg) -> np.ndarray:
    """Tool points (M, 3) mm of a D-H table ``rows`` ([(joint, a, alpha, d, theta_offset, beta)], base first) at
    commands (M, N) deg: the origin of the last frame."""
    cmd = np.atleast_2d(np.asarray(commands_deg, float))
    if len(rows) != cmd.shape[1] + 1:
        raise InputError(f"D-H table: {len(rows)} rows, expected the base row and {cmd.shape[1]} joints")
    t = np.broadcast_to(np.eye(4), (len(cmd), 4, 4))
    for k, (_, a, alpha, d, offset, beta) in enumerate(r[:6] for r in rows):
        q = offset + (cmd[:, k - 1] if k else np.zeros(len(cmd)))
        t = t @ row_transform(q, d, a, alpha, beta)
    return t[:, :3, 3]


def read_dh_table(path) -> list:
    """[(joint, a, alpha, d, theta_offset, beta)] of a table written by :func:`write_dh_table`, file order."""
    import csv

    from olti_drake.io.csvio import read_table, read_text

    table = read_table(path, COLUMNS[1:])  # (the numbers, checked by line; the joint names are text, read here)
    rows = list(csv.reader(t for t in read_text(path).splitlines() if t.strip() and not t.lstrip().startswith("#")))
    head = [c.strip() for c in rows[0]]
    if "joint" not in head:
        raise InputError(f"{path}: missing required column 'joint' (header has {', '.join(head)})")
    j = head.index("joint")
    return [(r[j].strip(),) + tuple(float(table[c][k]) for c in COLUMNS[1:]) for k, r in enumerate(rows[1:])]


def _cannot_hold(model) -> list:
    out = []
    if model.maps:
        out.append("the error maps' command- and direction-dependent part (their level is in theta_offset_deg)")
    if len(getattr(model, "compliance_joints", ())):
        out.append("the joint compliance (gravity-dependent)")
    out.append("the tool frame's orientation (the last frame's origin is the identified tool point; its axes are "
               "not the flange's)")
    return out


def residual(model, rows, poses: int = RESIDUAL_POSES, seed: int = 0):
    """(RMS, max) mm of ‖p_table − p_model‖ over ``poses`` seeded random commands and directions within the
    identified ranges."""
    from olti_drake.io.ur_kinematics import _ranges

    n = model.chain.n_joints
    rng = np.random.default_rng(seed)
    lo, hi = _ranges(model)
    cmd = rng.uniform(lo, hi, (poses, n))
    dirs = np.where(rng.random((poses, n)) < 0.5, -1.0, 1.0)
    d = np.linalg.norm(dh_positions(rows, cmd) - model.positions(cmd, dirs if model.maps else None), axis=1)
    return float(np.sqrt(np.mean(d ** 2))), float(d.max())


def write_dh_table(model, out_path, robot_file: str, result_path) -> dict:
    """Write ``out_path`` (module docstring); returns {"hayati": [joint pairs], "cannot_hold": [...],
    "residual_rms_mm", "residual_max_mm"}."""
    from olti_drake.io.csvio import write_table

    rows = dh_rows(model)
    rms, worst = residual(model, rows)
    names = [r[0] for r in rows]
    pairs = [f"{'root z' if k == 0 else names[k]}-{names[k + 1]}" for k, r in enumerate(rows[:-1]) if r[6]]
    cannot = _cannot_hold(model)
    cols = {c: [r[k] for r in rows] for k, c in enumerate(COLUMNS)}
    write_table(out_path, cols, {"joint": "%s", **{c: "%.15g" for c in COLUMNS[1:]}}, comments=[
        f"olti compensate --dh-out: identified kinematics of {robot_file} ({model.kind} model, result "
        f"{result_path}); mm and degrees",
        "standard (distal) D-H: row k maps frame k-1 to frame k by T = Rz(theta + theta_offset_deg) Tz(d_mm) "
        "Tx(a_mm) Rx(alpha_deg) Ry(beta_deg), theta the joint's command (0 on the base row: root frame -> frame 0)",
        "the tool point is the origin of the last frame; beta_deg = 0 on every classic D-H row",
        *([f"axes parallel within {PARALLEL_DEG:g} deg (classic D-H ill-conditioned: the common normal's d runs "
           f"to infinity): Hayati's row (d_mm = 0, beta_deg) for {', '.join(pairs)}"] if pairs else []),
        *(f"not held: {t}" for t in cannot),
        f"residual of the tool point, this table vs the identified model, {RESIDUAL_POSES} random poses within the "
        f"identified ranges: RMS {1e3 * rms:.4g} um, max {1e3 * worst:.4g} um"])
    return {"hayati": pairs, "cannot_hold": cannot, "residual_rms_mm": rms, "residual_max_mm": worst}
