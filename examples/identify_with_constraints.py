"""A MathematicalProgram experiment: identification with your own constraints and costs.

The identifier exposes its Drake ``MathematicalProgram``: one decision variable per
parameter, named as in the result (``L1_mm``, ``J2_forward_deg[3]``, ``P0_x_mm``,
``d0_0_mm``; mm and degrees), with the gauge constraint already in it. Add what
you know before solving::

    python examples/identify_with_constraints.py [data/paper000/campaign.csv]
"""

import sys

import numpy as np

from olti_drake.io.csvio import load_campaign
from olti_drake.estimation.identification import IdentificationOptions, Identifier


def second_difference(n: int) -> np.ndarray:
    """(n-2, n) matrix D with (D v)_i = v_i - 2 v_{i+1} + v_{i+2}: curvature of a map."""
    D = np.zeros((n - 2, n))
    for i in range(n - 2):
        D[i, i:i + 3] = [1.0, -2.0, 1.0]
    return D


def main(path="data/paper000/campaign.csv") -> int:
    data = load_campaign(path)
    plain = Identifier(data, IdentificationOptions(model="errormap")).solve()

    ident = Identifier(data, IdentificationOptions(model="errormap"))
    var = dict(zip(ident.names, ident.variables))
    # 1. A link length measured on a CMM: hold it (mm).
    ident.prog.AddBoundingBoxConstraint(325.0, 325.0, var["L1_mm"])
    # 2. The reflector P0 sits in a known pocket: keep it within +-0.5 mm of (650, -450).
    ident.prog.AddBoundingBoxConstraint([649.5, -450.5], [650.5, -449.5], [var["P0_x_mm"], var["P0_y_mm"]])
    # 3. A smoothness prior on the J2 forward map: weight * |D v|^2 (deg^2), as a quadratic cost.
    names = [n for n in ident.names if n.startswith("J2_forward_deg")]
    D = second_difference(len(names))
    weight = 1e3
    ident.prog.AddQuadraticCost(2 * weight * D.T @ D, np.zeros(len(names)), [var[n] for n in names],
                                is_convex=True)
    constrained = ident.solve()

    for label, r in (("plain", plain), ("constrained", constrained)):
        curvature = np.sum((second_difference(r.model.map2.n_nodes) @ r.model.map2.forward_deg) ** 2)
        print(f"{label:12s} L1 = {r.value('L1_mm'):.4f} mm  P0 = ({r.value('P0_x_mm'):.3f}, "
              f"{r.value('P0_y_mm'):.3f}) mm  J2 forward curvature {1e6 * curvature:.2f} mdeg^2  "
              f"residual RMS {1e3 * r.residual_rms_mm:.2f} um  [{r.solver}]")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
