"""The volumetric (3-axis machine, 21 ISO 230-1 error motions) side of ``olti identify``, ``predict`` and
``compensate`` (docs/machine_3d.md): read the files, call the layers below, write, print a summary.

The summary of ``olti identify CAMPAIGN.csv --model volumetric`` (whose route is :mod:`olti_drake.cli.identify`'s),
``olti predict R.json POINTS.csv`` and ``olti compensate R.json WANTED.csv [--tables DIR]`` on an
``olti-volumetric/1`` result (io.volumetric_io). Units: mm, µrad. Bad input raises ValueError (one line;
verbs.main prints it).
"""

import os

import numpy as np


def _preflight(args, files, inputs, dirs=()):
    from olti_drake.io.outputs import preflight

    preflight(files, [i for i in inputs if i], force=getattr(args, "force", False), dirs=dirs, create_dirs=bool(dirs))


def summary(res, doc: dict, data) -> str:
    """A short account of a volumetric identification: sizes, what was held and why, every motion's
    largest value and standard uncertainty, squareness, tools, stations, fit."""
    from olti_drake.estimation.calibration import suspect_readings_line
    from olti_drake.estimation.resolution import summary_line

    cfg = res.model.config
    f = res.fit
    lines = [f"volumetric model (21 ISO 230-1 error motions): {len(data)} readings, {len(data.commands_mm)} targets, "
             f"{data.n_stations} stations, {len(cfg.tools)} tool(s), {len(f.names)} unknowns; cubic B-splines every "
             f"<= {cfg.knot_spacing_mm:g} mm over x {cfg.travel_mm['X']}, y {cfg.travel_mm['Y']}, "
             f"z {cfg.travel_mm['Z']} mm",
             f"  observability: {res.observability}"]
    lines += [f"  note: {n} {why}" for n, why in res.held.items()]
    unc = doc["uncertainty"]
    for name, e in doc["error_motions"].items():
        if not e["identified"]:
            continue
        v, u = np.abs(e["values"]).max(), max(unc["error_motions"][name])
        scale, unit = (1e3, "um") if e["unit"] == "mm" else (1.0, "urad")
        lines.append(f"  {name:6s} {e['role']:12s} max |value| {scale * v:8.3f} {unit:4s} u (k=1) <= {scale * u:.3f} {unit}")
    lines.append("  squareness: " + ", ".join(f"{s} {v:+.2f} +- {unc['squareness_urad'][s]:.2f} urad"
                                              for s, v in doc["squareness_urad"].items()))
    for m, (t, u) in enumerate(zip(doc["tool_offsets_mm"], unc["tool_offsets_mm"])):
        how = "given (origin)" if m == 0 or not res.model.tool_groups else "estimated"
        lines.append(f"  tool {m}: ({t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}) mm {how}"
                     + (f", u {1e3 * max(u):.2f} um" if how == "estimated" else ""))
    for j, (P, L0) in enumerate(zip(res.stations_mm, res.dead_paths_mm)):
        lines.append(f"  station {j}: ({P[0]:.4f}, {P[1]:.4f}, {P[2]:.4f}) mm, dead path {L0:.4f} mm")
    lines.append(f"  residual RMS {1e3 * res.residual_rms_mm:.3f} um, {f.iterations} iterations, condition number "
                 f"{f.condition_number:.3g}, {f.solver}; converged: {f.converged_by}")
    lines.append(f"  gauge: {res.gauge}")
    check = summary_line(getattr(res, "resolution", None))
    lines += [check] if check else []
    lines += [f"  warning: {w}" for w in f.warnings]
    lines += [t for t in [suspect_readings_line(f.outliers)] if t]
    return "\n".join(lines)


def _read_points(path, names, n_tools: int):
    """(points (M, 3) mm, tool (M,), file lines) of a CSV with the three ``names`` and an optional ``tool``."""
    from olti_drake.errors import InputError
    from olti_drake.io.csvio import check_finite, read_table

    t = read_table(path, names, ("tool",), integer=("tool",))
    check_finite(t, path, names)
    tool = t["tool"].astype(int) if "tool" in t else np.zeros(len(t["_line"]), int)
    bad = np.flatnonzero((tool < 0) | (tool >= n_tools))
    if bad.size:
        raise InputError(f"{os.fspath(path)}:{t['_line'][bad[0]]}: column 'tool': {tool[bad[0]]} is not a tool of "
                         f"the result (0..{n_tools - 1})")
    return np.column_stack([t[c] for c in names]), tool, t["_line"]


def position_std(result, commands_mm, tool) -> np.ndarray:
    """Standard uncertainty (k = 1) of the predicted x, y, z (M, 3) mm (``VolumetricDocument.position_std``)."""
    return result.position_std(commands_mm, tool)


def predict(args) -> int:
    """``olti predict R.json POINTS.csv``: the actual tool point of every command by the identified model."""
    from olti_drake.io.csvio import write_table
    from olti_drake.io.volumetric_io import load_volumetric_result
    from olti_drake.model.volumetric3d import predict_positions

    res = load_volumetric_result(args.result)
    cfg = res.model.config
    c, tool, lines = _read_points(args.commands, ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm"), len(cfg.tools))
    try:
        p = predict_positions(cfg, res.motions, c, tool, args.outside, lines)
    except ValueError as e:
        raise ValueError(f"{args.commands}: {e} -- or run with --outside clamp") from None
    u = position_std(res, c, tool)
    cols = {"x_cmd_mm": c[:, 0], "y_cmd_mm": c[:, 1], "z_cmd_mm": c[:, 2], "tool": tool,
            "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "u_x_mm": u[:, 0], "u_y_mm": u[:, 1], "u_z_mm": u[:, 2]}
    fmt = {k: ("%d" if k == "tool" else "%.6f" if "cmd" in k else "%.9f") for k in cols}
    write_table(args.out, cols, fmt, comments=[
        f"olti predict: {args.result} applied to {args.commands}; mm",
        "x_mm, y_mm, z_mm: the tool point relative to the workpiece by the identified volumetric model; u_*: "
        "standard uncertainties (k = 1)" + (", motions held at the travel ends beyond it" if args.outside == "clamp"
                                            else "")])
    print(f"predicted {len(c)} tool points (volumetric model); max |actual - command - offset| "
          f"{1e3 * np.abs(p - c - cfg.tools[tool]).max():.2f} um, max u (k=1) {1e3 * u.max():.2f} um; wrote {args.out}")
    return 0


def table_paths(directory, config) -> list:
    """The files ``write_tables`` writes into ``directory`` (checked before the work)."""
    return ([os.path.join(directory, f"axis_{a}.csv") for a in "XYZ"]
            + [os.path.join(directory, f"grid_tool{m}.csv") for m in range(len(config.tools))])


def compensate(args) -> int:
    """``olti compensate R.json WANTED.csv``: machine commands that put the tool on the wanted points;
    ``--tables DIR``: the per-axis error-motion tables and the 3D grid of positioning-error vectors."""
    from olti_drake.io.csvio import write_table
    from olti_drake.io.volumetric_io import load_volumetric_result, write_tables
    from olti_drake.model.volumetric3d import compensate as invert

    if args.outside == "clamp":
        raise ValueError("--outside clamp: a compensated command beyond the identified travel would rest on error "
                         "motions never measured; volumetric compensation refuses such targets")
    res = load_volumetric_result(args.result)   # first: the tables it writes depend on its tools
    cfg = res.model.config
    if args.tables:  # before any work: the tables' sizes (olti_drake.limits)
        from olti_drake.model.volumetric3d import check_table_sizes

        check_table_sizes(cfg, args.pitch_mm or 10.0, args.grid_pitch_mm or 50.0)
    _preflight(args, [args.out] + (table_paths(args.tables, cfg) if args.tables else []), [args.result, args.targets],
               dirs=[args.tables] if args.tables else [])
    wanted, tool, lines = _read_points(args.targets, ("x_mm", "y_mm", "z_mm"), len(cfg.tools))
    try:
        q, err = invert(res.motions, cfg, wanted, tool, lines=lines)
    except ValueError as e:
        raise ValueError(f"{args.targets}: {e}") from None
    cols = {"x_cmd_mm": q[:, 0], "y_cmd_mm": q[:, 1], "z_cmd_mm": q[:, 2], "tool": tool,
            "x_mm": wanted[:, 0], "y_mm": wanted[:, 1], "z_mm": wanted[:, 2]}
    write_table(args.out, cols, {k: ("%d" if k == "tool" else "%.6f") for k in cols}, comments=[
        f"olti compensate: {args.result} inverted for the wanted points of {args.targets}; mm",
        "x_cmd_mm, y_cmd_mm, z_cmd_mm put tool 'tool' on x_mm, y_mm, z_mm (workpiece frame) by the volumetric model"])
    print(f"compensated {len(q)} points (volumetric model): max correction "
          f"{1e3 * np.abs(q - (wanted - cfg.tools[tool])).max():.2f} um, max residual {err.max():.2g} mm; wrote {args.out}")
    if args.tables:
        from olti_drake.io.outputs import make_dir

        make_dir(args.tables)
        for path in write_tables(args.tables, res.motions, cfg, args.pitch_mm or 10.0, args.grid_pitch_mm or 50.0):
            print(f"wrote {path}")
    return 0


def uncertainty(args) -> int:
    """``olti uncertainty R.json CAMPAIGN.csv``: the volumetric result re-solved on its campaign, then propagated
    linearly (JCGM 100) or by Monte Carlo (JCGM 101; batched trials, ``VolumetricIdentification.residual_rows``)
    with the budget's reading errors (default 001 Table 4); written in the result's uncertainty keys (mm, µrad)."""
    import time

    from olti_drake.cli.propagate import campaign_note, propagate
    from olti_drake.estimation.multilateration import load_machine_campaign
    from olti_drake.estimation.resolution import inflation_note
    from olti_drake.estimation.serial_uncertainty import prior_spread, smoothing_priors
    from olti_drake.estimation.volumetric import identification_at_result, volumetric_campaign
    from olti_drake.formats import UNCERTAINTY
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.csvio import check_campaign_matches
    from olti_drake.io.five_axis_io import file_sha256
    from olti_drake.io.outputs import write_json
    from olti_drake.io.volumetric_io import load_volumetric_result, uncertainty_block
    from olti_drake.model.budget import ReadingErrors
    from olti_drake.model.volumetric3d import ALL_MOTIONS

    t0 = time.perf_counter()
    res = load_volumetric_result(args.result)
    data = volumetric_campaign(load_machine_campaign(args.campaign))
    note = check_campaign_matches(res.doc, data, args.result)
    budget = budget_or_default(args.budget, "machine")
    ident, solved = identification_at_result(res, data, budget)
    x, errors = solved.fit.x, ReadingErrors(budget)
    std, cov, samples, extra, every = propagate(ident, x, errors, args)
    notes = list(extra.get("notes", []))
    priors = smoothing_priors(ident, x)
    if priors.Q is not None:  # (the smoothness prior's own spread, as the identification weighed it)
        u2 = float(np.mean(errors.std(ident.beam_lengths(x)) ** 2))
        if cov is not None:
            cov = prior_spread(ident, x, priors, u2, cov=cov)
        else:
            every = prior_spread(ident, x, priors, u2, samples=every, seed=args.seed)
        notes += priors.notes
    C = cov if cov is not None else np.cov(every, rowvar=False)
    n, nj = ident.n_model, data.n_stations
    E = np.zeros((res.model.n_params, len(x)))  # the model's parameters from x (held: 0)
    E[ident.free_cols, np.arange(n)] = 1.0
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    positions = {name[3]: res.doc["error_motions"][name]["positions_mm"] for name in ALL_MOTIONS}
    own = (res.model, E @ C @ E.T, positions, std[n:n + 3 * nj].reshape(nj, 3), std[n + 3 * nj:n + 4 * nj])
    block = uncertainty_block(*own)
    notes += [t for t in [inflation_note(res.doc)] if t]
    extra.update(notes=notes)
    campaign_note(extra, note)
    out = {"format": UNCERTAINTY, "method": args.method, "k": 1, **block,
           "expanded": dict(k=args.k, **uncertainty_block(*own, scale=args.k)),
           "budget": budget.name, "parameters": {"names": list(ident.names), "std": std.tolist()}, **extra,
           "result": args.result, "result_sha256": file_sha256(args.result), "campaign": args.campaign,
           "elapsed_s": round(time.perf_counter() - t0, 3)}
    write_json(args.out, out)
    print(f"uncertainty ({args.method}) of the volumetric result {args.result} on {len(data)} readings; budget "
          f"{budget.name!r}" + (f"; {len(every)} trials, seed {args.seed}" if every is not None else ""))
    for name, u in block["error_motions"].items():
        scale, unit = (1e3, "um") if name[2] in "XYZ" else (1.0, "urad")
        if max(u) > 0:
            print(f"  {name:6s} U (k = {args.k:g}) <= {scale * args.k * max(u):.3f} {unit}")
    for line in notes:
        print(f"  note: {line}")
    print(f"wrote {args.out}")
    return 0
