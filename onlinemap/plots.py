"""Figures (matplotlib). Functions build ``matplotlib.figure.Figure`` objects directly, without
pyplot's global state, so they work the same from the CLI (saved as PNG, no display needed)
and in a notebook (``display(fig)`` or a figure as a cell's last expression)."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib.colors
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from .belief import Belief
from .errors import ModelError
from .estimators import Trajectory
from .model import GridModel
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


def plot_belief(model: GridModel, belief: Belief, true_map: np.ndarray | None = None,
                true_location: int | None = None) -> Figure:
    """The location and the map of one belief, drawn on the grid.

    Corridors (one row): bars of P(L_t = i) and stacked bars of P(m_i = k) per label. 2D worlds:
    an image of P(L_t) and an image of the most likely label per cell, faded where it is
    uncertain (opacity = its probability). ``true_map`` (N,) and ``true_location`` are marked when
    given (dots on the wrong cells, a star on the robot). A belief of another model's size
    raises ModelError. Cost O(N K).
    """
    if belief.location.shape != (model.n_cells,) or belief.map.shape != (model.n_cells, model.n_labels):
        raise ModelError(f"a belief over {belief.n_cells} cells x {belief.n_labels} labels does not fit {model} "
                         f"({model.n_cells} cells x {model.n_labels} labels): give the model the belief is of")
    fig = Figure(figsize=(10, 3.2) if model.rows == 1 else (10, 4.2), layout="constrained")
    ax_loc, ax_map = fig.subplots(1, 2)
    cells = np.arange(model.n_cells)
    best = belief.map_estimate
    wrong = None if true_map is None else np.flatnonzero(best != np.asarray(true_map))
    if model.rows == 1:
        ax_loc.bar(cells, belief.location, color="tab:purple")
        ax_loc.set(xlabel="cell", ylabel="P(location)", ylim=(0, 1), title=f"location at t = {belief.t}")
        bottom = np.zeros(model.n_cells)
        for k, name in enumerate(model.label_names):
            ax_map.bar(cells, belief.map[:, k], bottom=bottom, label=name, color=f"C{k}")
            bottom += belief.map[:, k]
        ax_map.set(xlabel="cell", ylabel="P(label)", ylim=(0, 1), title="map marginals")
        ax_map.legend(loc="upper right", fontsize="x-small", ncols=min(model.n_labels, 4))
        if true_location is not None:
            ax_loc.plot([true_location], [1.0], marker="*", color="black", markersize=12, clip_on=False)
        if wrong is not None:
            ax_map.plot(wrong, np.full(len(wrong), 1.02), "v", color="black", clip_on=False, label="wrong")
        ax_loc.set_xticks(cells)
        ax_map.set_xticks(cells)
        return fig
    shape = model.shape
    image = ax_loc.imshow(belief.location.reshape(shape), cmap="magma", vmin=0, interpolation="nearest")
    fig.colorbar(image, ax=ax_loc, fraction=0.046, label="P(location)")
    ax_loc.set(title=f"location at t = {belief.t}", xlabel="column", ylabel="row")
    colours = np.array([matplotlib.colors.to_rgb(f"C{k}") for k in range(model.n_labels)])
    rgba = np.concatenate([colours[best], belief.map.max(axis=1)[:, None]], axis=1).reshape(*shape, 4)
    ax_map.imshow(rgba, interpolation="nearest")
    ax_map.set(title="most likely label (faded: uncertain)", xlabel="column", ylabel="row")
    for k, name in enumerate(model.label_names):
        ax_map.scatter([], [], marker="s", color=colours[k], label=name)
    ax_map.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="x-small")
    if true_location is not None:
        row, col = divmod(int(true_location), model.cols)
        ax_loc.plot(col, row, marker="*", color="cyan", markersize=12)
    if wrong is not None:
        rows, cols = np.divmod(wrong, model.cols)
        ax_map.plot(cols, rows, ".", color="black", markersize=4, label="wrong")
    return fig


DOOR_COLOURS = {"free": "white", "wall": "#404040", "open_door": "tab:green",
                "closed_door": "tab:red"}  # plot_building's palette for door-world labels


def label_colours(model: GridModel) -> np.ndarray:
    """(K, 3) RGB per label: :data:`DOOR_COLOURS` for door-world labels, matplotlib's C0, C1, ... otherwise."""
    door = set(model.label_names) == set(DOOR_COLOURS)
    return np.array([matplotlib.colors.to_rgb(DOOR_COLOURS[name] if door else f"C{k}")
                     for k, name in enumerate(model.label_names)])


def plot_building(model: GridModel, labels: np.ndarray, *, title: str = "", start: bool = True) -> Figure:
    """A map drawn on its grid (a generated building, a read layout, any 2D world): one colour per
    label (:func:`label_colours`: free white, walls dark grey, open doors green, closed doors red)
    with a legend of the labels present, and the start cell starred unless ``start=False``.
    labels (N,) or (rows, cols) ints in 0..K-1. Cost O(N)."""
    labels = np.asarray(labels)
    if model.rows == 1 or labels.size != model.n_cells or labels.dtype.kind not in "iu" or \
            labels.min() < 0 or labels.max() >= model.n_labels:
        raise ValueError(f"plot_building draws a 2D map of {model.n_cells} labels in 0..{model.n_labels - 1}, "
                         f"got {labels.dtype} {labels.shape} for {model}")
    labels = labels.reshape(model.shape)
    colours = label_colours(model)
    height = 5.0
    fig = Figure(figsize=(min(14.0, height * model.cols / model.rows + 2.2), height), layout="constrained")
    ax = fig.subplots()
    ax.imshow(colours[labels], interpolation="nearest")
    for k in np.unique(labels):
        ax.scatter([], [], marker="s", s=60, color=colours[k], edgecolor="black", linewidth=0.5,
                   label=model.label_names[k])
    if start:
        row, col = divmod(model.start, model.cols)
        ax.plot(col, row, marker="*", color="tab:blue", markersize=12, linestyle="none", label="start")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="small")
    ax.set(title=title or f"{model.rows} x {model.cols} floor", xlabel="column", ylabel="row")
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
