"""How fast is the volumetric 3D model (21 ISO 230-1 error motions), and a fit with it?

    python benchmarks/bench_volumetric3d.py

On the default serial X–Y–Z machine (travel 400 × 300 × 250 mm, cubic B-splines
every 50 mm: 147 parameters), for 600 seeded random targets × 2 tools
(1200 tool points):

- analytic: ``VolumetricModel.jacobian`` — positions and the (1200, 3, 147)
  Jacobian w.r.t. every coefficient and squareness (best of 5);
- finite differences: the baseline in the same run — central differences of
  ``VolumetricModel.positions`` over the 147 parameters (best of 2); the two
  must agree to 1e-6 mm per unit parameter;
- fit: Gauss–Newton on the 3D targets of a synthetic truth (sums of sines, not
  in the basis) measured in an unknown frame (rigid 6-dof gauge), the
  test-only solver of ``tests/model/test_volumetric3d.py`` (until the identifier is
  wired); 600 targets × 3 tools so that all 21 motions are separable (with 2
  tools one rotation of Z about the tool line is not: docs/machine_3d.md);
- observability of the 2-tool layout (SVD of the projected Jacobian);
- volumetric identification: ``estimation.volumetric.identify_volumetric`` on the
  3-tool distance campaign of ``tests/cli/test_volumetric_cli.py`` (308 commands × 3
  tools × 5 stations = 4620 readings, truth outside the basis, 001 Table 4 noise):
  observability before solving, LM with Drake step programs, budget covariance
  (best of 2); baseline in the same run: ``scipy.optimize.least_squares`` (trf,
  the same residuals and analytic Jacobian, no observability, no covariance);
  the two must agree to 1e-3 of a standard uncertainty.

Exits 1 when the analytic Jacobian disagrees with finite differences, the fit or
the identification takes 10 s or more (issue target: volumetric identification
< 10 s), or the identification disagrees with the baseline.
Units: mm, µrad; times in ms.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "model"))
from timing import best_of, cpu_busy  # noqa: E402

from olti_drake.threads import single_thread_blas  # noqa: E402
from olti_drake.model.volumetric3d import (MachineConfig, VolumetricModel, observability,  # noqa: E402
                                           synthetic_truth, tool_positions)
from test_volumetric3d import THREE_TOOLS, TWO_TOOLS, campaign, fit_targets, motion_errors  # noqa: E402

TARGET_FIT_S = 10.0


def identification_timing():
    """(t_identify s, t_scipy s, max |difference| / u, residual RMS um) on the 3-tool CLI test campaign."""
    import tempfile

    from scipy.optimize import least_squares

    from olti_drake.estimation.multilateration import load_machine_campaign
    from olti_drake.estimation.volumetric import VolumetricIdentification, VolumetricOptions, volumetric_campaign
    from test_volumetric_cli import NOMINAL_TOOLS, simulate_campaign

    with tempfile.TemporaryDirectory() as d:
        simulate_campaign(3, Path(d) / "campaign.csv")
        data = volumetric_campaign(load_machine_campaign(Path(d) / "campaign.csv"))
    options = VolumetricOptions(tool_offsets_mm=NOMINAL_TOOLS, knot_spacing_mm=50.0)
    t_id, res = best_of(lambda: VolumetricIdentification(data, options).solve(), 2)
    ident = VolumetricIdentification(data, options)

    def baseline():
        return least_squares(lambda x: ident.residuals(x)[0], ident.x0, jac=lambda x: ident.residuals(x)[1].toarray(),
                             method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    with single_thread_blas():
        t_sp, sol = best_of(baseline, 2)
    std = np.sqrt(np.diag(res.covariance))
    diff = np.abs(ident.theta(sol.x) - res.params)[std > 0] / std[std > 0]
    return t_id, t_sp, float(diff.max()), 1e3 * res.residual_rms_mm


def finite_difference_jacobian(model, c, t, x, step=1e-3):
    J = np.empty((len(c), 3, model.n_params))
    for i in range(model.n_params):
        d = np.zeros(model.n_params)
        d[i] = step
        J[:, :, i] = (model.positions(c, t, x + d) - model.positions(c, t, x - d)) / (2 * step)
    return J


def main() -> int:
    busy = cpu_busy()
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    c, t = campaign(cfg, 600)
    x = model.fit_function(synthetic_truth(cfg, 1))
    t_an, (p, J) = best_of(lambda: model.jacobian(c, t, x), 5)
    t_pos, _ = best_of(lambda: model.positions(c, t, x), 5)
    t_fd, J_fd = best_of(lambda: finite_difference_jacobian(model, c, t, x), 2)
    agree = float(np.abs(J - J_fd).max())
    t_obs, obs = best_of(lambda: observability(model, c, t), 1)

    cfg3 = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    model3 = VolumetricModel(cfg3)
    truth = synthetic_truth(cfg3, 1)
    c3, t3 = campaign(cfg3, 600, 1)
    measured = tool_positions(cfg3, truth, c3, t3) + [1.0, -2.0, 0.5]
    with single_thread_blas():  # as the identifier's solver (olti_drake/calibration.py) does
        t_fit, params = best_of(lambda: fit_targets(model3, c3, t3, measured), 1)
    err = motion_errors(model3, params, truth)
    t_id, t_sp, agree_id, rms_id = identification_timing()

    print(f"volumetric 3D model: {model.n_params} parameters, {len(c)} tool points (600 targets x 2 tools)"
          f"{'' if busy is None else f'; CPUs {100 * busy:.0f}% busy with other work'}")
    print(f"  positions                 {1e3 * t_pos:8.1f} ms")
    print(f"  positions + Jacobian      {1e3 * t_an:8.1f} ms (analytic)")
    print(f"  finite-difference Jacobian{1e3 * t_fd:8.1f} ms  -> analytic is {t_fd / t_an:.0f}x faster; "
          f"max |difference| {agree:.1e}")
    print(f"  observability (2 tools)   {1e3 * t_obs:8.1f} ms: {len(obs.inseparable)} motions inseparable "
          f"(null dimension {obs.null_dimension})")
    print(f"  fit, 600 targets x 3 tools{1e3 * t_fit:8.1f} ms (target < {TARGET_FIT_S:.0f} s); worst error "
          f"{max(v for k, v in err.items() if k[2] in 'XYZ' and k not in ('E_B0Z', 'E_A0Z')) * 1e3:.3f} um, "
          f"{max(v for k, v in err.items() if k[2] in 'ABC' or k in ('E_C0Y', 'E_B0Z', 'E_A0Z')):.3f} urad")
    print(f"  identification (4620 readings, 3 tools, 173 unknowns){1e3 * t_id:8.1f} ms (target < {TARGET_FIT_S:.0f} s; "
          f"observability + LM + covariance); scipy least_squares baseline {1e3 * t_sp:8.1f} ms -> ratio "
          f"{t_id / t_sp:.2f}; max |difference| {agree_id:.1e} u; residual RMS {rms_id:.3f} um")
    ok = agree < 1e-6 and t_fit < TARGET_FIT_S and t_id < TARGET_FIT_S and agree_id < 1e-3
    if not ok:
        print("FAILED: " + ("Jacobian disagrees with finite differences" if agree >= 1e-6 else
                            "identification disagrees with the baseline" if agree_id >= 1e-3 else "fit too slow"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
