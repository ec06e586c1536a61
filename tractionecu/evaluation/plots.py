"""Figures of a replay: the paper's Fig. 6 (μ per wheel and ρ_s over time) and Fig. 5 (μ(s) per soil).

Drawn with matplotlib (the ``maps`` extra), imported only when a figure is drawn.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..model.mucurve import SOIL_CLASSES
from ..model.vehicle import WHEELS
from .scoring import S_GRID, Truth

TRUTH_STYLE = dict(color="black", lw=1.8, ls="--", zorder=3, label="true")
"""Fig. 6's truth: dashed, thicker and drawn over the estimate, so it shows where the two coincide."""
ESTIMATE_STYLE = dict(color="tab:blue", lw=1.0, alpha=0.85, zorder=2, label="AUKF-FS")


def plot_run(out: Path, arrays: dict[str, Any], truth: Truth | None, sc: dict[str, Any] | None) -> list[str]:
    """Write the paper's Fig. 6 (μ per wheel and ρ_s over time) and Fig. 5 (μ(s) per soil) as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = arrays["t"]
    tr = t - t[0]
    paths = []
    fig, axes = plt.subplots(5, 1, figsize=(10, 11), sharex=True)
    if truth is not None:
        k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    for i, w in enumerate(WHEELS):
        ax = axes[i]
        if truth is not None:
            ax.plot(tr, truth.mu[k, i], **TRUTH_STYLE)
        ax.plot(tr, arrays["mu"][:, i], **ESTIMATE_STYLE)
        ax.set_ylabel(f"μ {w} [-]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    ax = axes[4]
    if truth is not None:
        ax.plot(tr, truth.rho_s[k], **TRUTH_STYLE)
    ax.plot(tr, arrays["rho_s"], **ESTIMATE_STYLE)
    ax.set_ylabel("ρ_s [-]")
    ax.set_xlabel("t [s]")
    ax.grid(alpha=0.3)
    fig.suptitle("Adhesion per wheel and soil rolling resistance (paper Fig. 6)")
    paths.append(_save(plt, fig, out / "fig6_mu_rho.png"))

    if sc and sc.get("curves"):
        fig, ax = plt.subplots(figsize=(7, 5))
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for j, (name, c) in enumerate(sc["curves"].items()):
            col = colors[j % len(colors)]
            ax.plot(S_GRID, SOIL_CLASSES[c["class_true"]].mu(S_GRID, c["a_true"]), color=col, lw=2.5, alpha=0.45,
                    label=f"{name} true (a={c['a_true']:.2f})")
            ax.plot(S_GRID, SOIL_CLASSES[c["class_identified"]].mu(S_GRID, c["a_identified"]), color=col, lw=1.2,
                    ls="--", label=f"{name} identified (a={c['a_identified']:.3f}, R²={sc['r2_mu_curve'][name]:.4f})")
        ax.set_xlabel("slip s [-]")
        ax.set_ylabel("μ [-]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        ax.set_title("Identified vs true μ(s) per soil (paper Fig. 5)")
        paths.append(_save(plt, fig, out / "fig5_mu_curves.png"))
    return paths


def _save(plt: Any, fig: Any, path: Path) -> str:
    """Lay out, write (110 dpi) and close one figure; return its path."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)
