"""Figures 4.11-4.14 of seed 2 and its cost-precision chart, as PNG (Matplotlib)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from commands.budget.model import Catalogue, budget_table, ins_error, lx_max

if TYPE_CHECKING:
    from matplotlib.axes import Axes

# The seed's worked example (system 1 at 300 m): e_T = 1.005 deg, alpha = 3 mrad.
H, THETA, E_T, ALPHA = 300.0, 30.0, 1.005, math.degrees(0.003)


def altitude_chart(ax: Axes, catalogue: Catalogue) -> None:
    """Fig. 4.11: L_xMAX grows linearly with the flying height."""
    w = lx_max(1.0, THETA, E_T, ALPHA)  # eq. 4.24-4.25: L_xMAX = h w
    h = np.linspace(0, 1500, 151)
    ax.plot(h, h * w)
    ax.set(xlabel="flying height h [m]", ylabel="L_xMAX [m]", title=f"Fig. 4.11: L_xMAX = h w, w = {w:.4f}")
    ax.grid(alpha=0.3)


def scan_angle_chart(ax: Axes, catalogue: Catalogue) -> None:
    """Fig. 4.12: L_xMAX against the maximum scan angle."""
    theta = np.linspace(0, 60, 121)
    ax.plot(theta, [lx_max(H, t, E_T, ALPHA) for t in theta])
    ax.set(
        xlabel="maximum scan angle θ_MAX [°]",
        ylabel="L_xMAX [m]",
        title="Fig. 4.12: h = 300 m, e_T = 1.005°, α = 3 mrad",
    )
    ax.grid(alpha=0.3)


def divergence_chart(ax: Axes, catalogue: Catalogue) -> None:
    """Fig. 4.13: L_xMAX against the beam divergence."""
    alpha = np.linspace(0.1, 5, 50)  # mrad
    ax.plot(alpha, [lx_max(H, THETA, E_T, math.degrees(a / 1000)) for a in alpha])
    ax.set(
        xlabel="beam divergence α [mrad]", ylabel="L_xMAX [m]", title="Fig. 4.13: h = 300 m, θ_MAX = 30°, e_T = 1.005°"
    )
    ax.grid(alpha=0.3)


def ins_error_chart(ax: Axes, catalogue: Catalogue) -> None:
    """Fig. 4.14: the horizontal error of an INS attitude error."""
    e = np.linspace(0, 2, 101)
    ax.plot(e, [ins_error(H, x) for x in e])
    ax.set(xlabel="INS attitude error e_θ [°]", ylabel="e_SNI [m]", title="Fig. 4.14: e_SNI = h tan(e_θ), h = 300 m")
    ax.grid(alpha=0.3)


def cost_precision_chart(ax: Axes, catalogue: Catalogue) -> None:
    """Total error at t = 0 against cost, for every system in range at 300, 600 and 1200 m (§4.6)."""
    for height, marker in ((300.0, "o"), (600.0, "s"), (1200.0, "^")):
        rows = [r for r in budget_table(catalogue, height) if r.in_range and r.cost_usd is not None]
        label = f"h = {height:g} m" if rows else f"h = {height:g} m: no system in range"
        ax.scatter([r.cost_usd / 1000 for r in rows], [r.total_t0_m for r in rows], marker=marker, label=label)
        for r in rows:
            ax.annotate(
                r.system, (r.cost_usd / 1000, r.total_t0_m), fontsize=7, xytext=(3, 3), textcoords="offset points"
            )
    ax.set(xlabel="cost [thousand USD]", ylabel="total error at t = 0 [m]", title="Cost vs precision (seed 2, §4.6)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend()


#: file name, figure size (inches), what draws it
CHARTS = (
    ("fig_4_11_altitude.png", (6, 4), altitude_chart),
    ("fig_4_12_scan_angle.png", (6, 4), scan_angle_chart),
    ("fig_4_13_divergence.png", (6, 4), divergence_chart),
    ("fig_4_14_ins_error.png", (6, 4), ins_error_chart),
    ("cost_precision.png", (7, 4.5), cost_precision_chart),
)


def write_plots(catalogue: Catalogue, folder: Path) -> list[Path]:
    """Write the five charts into *folder*; return their paths."""
    matplotlib.use("Agg")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, size, draw in CHARTS:
        fig, ax = plt.subplots(figsize=size)
        draw(ax, catalogue)
        path = folder / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        out.append(path)
    return out
