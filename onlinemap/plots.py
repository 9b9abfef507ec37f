"""Figures (matplotlib). Functions build ``matplotlib.figure.Figure`` objects directly, without
pyplot's global state, so they work the same from the CLI (saved as PNG, no display needed)
and in a notebook (``display(fig)`` or a figure as a cell's last expression)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from .estimators import Trajectory
from .simulate import Run


def plot_location(ax: Axes, location: np.ndarray, true_path: np.ndarray, title: str = "") -> None:
    """Heat map of P(L_t = i) (time on x, cell on y) with the true path overlaid.
    location (T, N), true_path (T,)."""
    steps, cells = location.shape
    image = ax.imshow(location.T, origin="lower", aspect="auto", cmap="magma", vmin=0, vmax=1,
                      extent=(-0.5, steps - 0.5, -0.5, cells - 0.5), interpolation="nearest")
    ax.plot(np.arange(steps), true_path, color="cyan", marker="o", markersize=3, linewidth=1,
            label="true location")
    ax.set(xlabel="step t", ylabel="cell", title=title or "P(location)")
    ax.legend(loc="upper left", fontsize="x-small", framealpha=0.6)
    ax.figure.colorbar(image, ax=ax, fraction=0.05)


def plot_map(ax: Axes, maps: np.ndarray, true_map: np.ndarray, label: int = 1, title: str = "") -> None:
    """Heat map of P(m_i,t = label) (time on x, cell on y); the true labels are marked to the
    right of the last step (filled: the cell's true label is ``label``). maps (T, N, K), true_map (N,)."""
    steps, cells, _ = maps.shape
    image = ax.imshow(maps[:, :, label].T, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=1,
                      extent=(-0.5, steps - 0.5, -0.5, cells - 0.5), interpolation="nearest")
    is_label = np.asarray(true_map) == label
    x = np.full(cells, steps - 0.5 + 0.6)
    ax.scatter(x[is_label], np.flatnonzero(is_label), marker="s", color="black", s=18, clip_on=False)
    ax.scatter(x[~is_label], np.flatnonzero(~is_label), marker="s", facecolor="white", edgecolor="black",
               s=18, clip_on=False)
    ax.set_xlim(-0.5, steps + 0.4)
    ax.set(xlabel="step t (squares: true map)", ylabel="cell", title=title or f"P(label = {label})")
    ax.figure.colorbar(image, ax=ax, fraction=0.05)


def estimators_figure(run: Run, trajectories: dict[str, Trajectory], label: int = 1) -> Figure:
    """One row per estimator: location posterior over time, then map marginals over time."""
    rows = len(trajectories)
    height = 2.6 * rows  # fixed margins in inches; a manual layout draws twice as fast as "constrained"
    fig = Figure(figsize=(10, height))
    axes = fig.subplots(rows, 2, squeeze=False, gridspec_kw=dict(
        left=0.06, right=0.98, wspace=0.22, hspace=0.55, top=1 - 0.3 / height, bottom=0.5 / height))
    for (name, trajectory), (ax_loc, ax_map) in zip(trajectories.items(), axes):
        plot_location(ax_loc, trajectory.location, run.locations, f"{name}: P(location)")
        plot_map(ax_map, trajectory.map, run.final_map, label, f"{name}: P(label = {label})")
    return fig


def study_figure(summary: pd.DataFrame, confidence: float = 0.95) -> Figure:
    """Fractions of runs astray on the way back and with a wrong map per estimator, with their intervals (the
    columns of :func:`onlinemap.reproduce.random_corridor_study`'s summary)."""
    fig = Figure(figsize=(9, 0.32 * len(summary) + 1.5), layout="constrained")
    ax = fig.subplots()
    y = np.arange(len(summary))
    for offset, column, colour in ((-0.2, "astray_way_back", "tab:red"), (0.2, "wrong_map", "tab:blue")):
        value = summary[column].to_numpy()
        error = np.stack([value - summary[f"{column}_low"], summary[f"{column}_high"] - value])
        ax.barh(y + offset, value, height=0.4, xerr=error, color=colour, alpha=0.8, capsize=2,
                label=column.replace("_", " "))
    ax.set_yticks(y, summary["estimator"], fontsize="small")
    ax.invert_yaxis()
    ax.set(xlim=(0, 1), xlabel=f"fraction of {int(summary['runs'].iloc[0])} random runs "
                               f"({confidence:.0%} Wilson intervals)")
    ax.legend(loc="lower right")
    return fig


def slug(text: str) -> str:
    """A file-name-safe version of an estimator label."""
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def save(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG (creating the directory); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
