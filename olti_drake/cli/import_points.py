"""``olti import-points EXPORT --joints LOG.csv --out campaign.csv``: a laser tracker's point export and the
robot's joint log as the point campaign of formats.md (the reading, matching and writing:
:mod:`olti_drake.io.tracker_exports`). Prints what was matched and skipped."""

from __future__ import annotations


def _lines(lines, most: int = 5) -> str:
    shown = ", ".join(str(v) for v in lines[:most])
    return shown + (f" and {len(lines) - most} more" if len(lines) > most else "")


def import_points(args) -> int:
    from olti_drake.io.outputs import preflight
    from olti_drake.io.tracker_exports import import_points as run

    preflight([], [args.export, args.joints], measurements=[args.out])
    s = run(args.export, args.joints, args.out, layout=args.format, columns=args.columns, units=args.units,
            match=args.match, max_dt_s=args.max_dt_s)
    how = f"by {s.match}" + (f" within {s.max_dt_s:g} s" if s.match == "time" else "")
    print(f"matched {s.matched} points {how} ({'SpatialAnalyzer-style' if s.layout == 'sa' else 'CSV'} export, "
          f"units {s.units} from {s.units_from}, converted to mm)")
    if s.skipped_points:
        print(f"skipped {len(s.skipped_points)} export point(s) without a log row: {args.export} line(s) "
              f"{_lines(s.skipped_points)}")
    if s.skipped_log:
        print(f"skipped {len(s.skipped_log)} log row(s) without a point: {args.joints} line(s) "
              f"{_lines(s.skipped_log)}")
    print(f"wrote {args.out}")
    return 0
