"""Figures in the manner of paper 000 (matplotlib, PNG, no display needed).

Units on every axis: mm and mdeg.
"""

import os

import numpy as np


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")  # headless: files only
    import matplotlib.pyplot as plt
    return plt


def plot_poses_and_reflectors(setup, campaign, path):
    """Command positions p*(k) and reflector positions, as 000 Fig. 5."""
    from .kinematics import forward_kinematics

    plt = _pyplot()
    r = setup.scenario.robot
    c = campaign.columns
    p = forward_kinematics(c["theta1_deg"], c["theta2_deg"], r.nominal_L1_mm, r.nominal_L2_mm)[0]
    fig, ax = plt.subplots(figsize=(9, 6))
    ax.plot(p[:, 0], p[:, 1], ".", color="k", ms=3, label="command positions p*(k)")
    lost = c["valid"] < 0.5
    if lost.any():
        ax.plot(p[lost, 0], p[lost, 1], "x", color="tab:orange", label="beam lost")
    P, P_est = setup.reflectors_mm, setup.reflectors_estimate_mm
    ax.plot(P[:, 0], P[:, 1], "o", mfc="none", color="tab:red", ms=10, label="reflectors (true)")
    ax.plot(P_est[:, 0], P_est[:, 1], "+", color="tab:blue", ms=10, label="reflectors (estimate)")
    for j, q in enumerate(P):
        ax.annotate(f"P{j + 1}", q, textcoords="offset points", xytext=(8, 8))
    ax.plot([0], [0], "s", color="gray", label="J1 axis")
    ax.set(xlabel="X, mm", ylabel="Y, mm", title="Command positions and reflectors (000 Fig. 5)")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_truth_maps(setup, path):
    """The simulated truth Δθ(θ*, ±1) of J1 and J2, as 000 Fig. 6 (continuous + grid samples)."""
    plt = _pyplot()
    r = setup.scenario.robot
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, axis, cmds in ((axes[0], "J1", setup.plan.theta1_deg), (axes[1], "J2", setup.plan.theta2_deg)):
        dev = getattr(r, axis)
        nodes = np.unique(cmds[setup.plan.measure])
        dense = np.linspace(nodes[0], nodes[-1], 400)
        for d, color, label in ((1, "tab:red", "positive (+1)"), (-1, "tab:blue", "negative (-1)")):
            ax.plot(dense, 1e3 * dev(dense, d), color=color, label=f"truth, {label}")
            ax.plot(nodes, 1e3 * dev(nodes, d), "o", color=color, ms=4)
        ax.set(xlabel=f"{axis} command angle, deg", ylabel="angular positioning deviation, mdeg",
               title=f"{axis}: simulated truth (000 Fig. 6 style)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_campaign_figures(setup, campaign, out_dir):
    """Write the campaign's figures into ``out_dir``; returns their paths."""
    os.makedirs(out_dir, exist_ok=True)
    return [plot_poses_and_reflectors(setup, campaign, os.path.join(out_dir, "fig5_poses_reflectors.png")),
            plot_truth_maps(setup, os.path.join(out_dir, "fig6_truth_maps.png"))]
