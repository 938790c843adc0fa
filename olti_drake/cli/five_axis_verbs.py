"""``olti identify --machine`` (its summary) and ``olti predict`` of a five-axis machine result (``olti-machine5/1``;
formats.md, "Five-axis machine tools"; docs/five_axis.md). Units: mm, deg, µrad."""

import numpy as np


def summary(ident, fit, doc) -> str:
    """A few lines: readings, residual RMS (µm), every identified location error with its u (k = 1), what is held."""
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
    return "\n".join(lines)


def predict(args) -> int:
    """``olti predict R.json POINTS.csv --out P.csv``: the tool point in the workpiece frame (mm) of every command
    by the identified machine, and its standard uncertainty (k = 1), sqrt(diag(J C Jᵀ))
    (:func:`olti_drake.model.propagation.predicted_std`; 0 when the result stores no covariance)."""
    from olti_drake.io.five_axis_io import load_machine5_result, read_five_axis_points, write_predictions
    from olti_drake.model.propagation import predicted_std

    res = load_machine5_result(args.result)
    c, d, tool, _ = read_five_axis_points(args.commands, res.machine)
    if res.errors.bidirectional and res.errors.maps and d is None:
        d = np.ones((len(c), len(res.machine.rotary)))
        print("note: the points carry no approach directions: +1 (forward branch of the maps) taken")
    pm = res.position_model(c, d, tool)
    p, J = pm.jacobian(res.x)
    u = (predicted_std(J.tocsr(), res.covariance, dim=3) if res.covariance is not None else np.zeros_like(p))
    write_predictions(args.out, c, d, tool, res.machine, p, u)
    print(f"predicted {len(c)} tool points (five-axis machine, workpiece frame); max u (k=1) {1e3 * u.max():.2f} um; "
          f"wrote {args.out}")
    return 0
