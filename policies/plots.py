"""Figures for exploration runs (matplotlib, no pyplot state: they work on any backend).

Both take the long table of :func:`onlinemap.studies.exploration.compare_planners` (columns ``planner``,
``seed``, ``t``, ``map_error``, ``door_error``, ``true_location``, ...).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from onlinemap.model import DOOR_LABELS, GridModel, WALL, door_cells

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn, not with the package
    from matplotlib.figure import Figure


ERROR_TITLES = {"map_error": "map error (mean 1 - P(true label))",
                "door_error": "door-state error (door cells)",
                "location_error": "location error (1 - P(true cell))"}


def plot_errors(table: pd.DataFrame, axes=None, columns=("map_error", "door_error")) -> "Figure":
    """Errors over time (``columns`` of the table, default map error and door-state error), one
    line per planner: the mean over seeds with a band of +- one standard error. ``axes``: one
    matplotlib axis per column (created when None)."""
    from matplotlib.figure import Figure

    if axes is None:
        figure = Figure(figsize=(5.5 * len(columns), 3.8), layout="constrained")
        axes = np.atleast_1d(figure.subplots(1, len(columns)))
    for ax, column in zip(axes, columns):
        title = ERROR_TITLES.get(column, column)
        for planner, runs in table.groupby("planner", sort=False):
            by_step = runs.groupby("t")[column]
            mean, sem = by_step.mean(), by_step.sem().fillna(0.0)
            ax.plot(mean.index, mean.to_numpy(), label=planner)
            ax.fill_between(mean.index, mean - sem, mean + sem, alpha=0.2)
        n_seeds = int(table.groupby("planner")["seed"].nunique().max())
        ax.set(title=title, xlabel="step", ylim=(0, None))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"mean over {n_seeds} seed{'s' * (n_seeds > 1)}")
    axes[0].legend()
    return axes[0].figure


def plot_visits(model: GridModel, true_map, table: pd.DataFrame, axes=None) -> "Figure":
    """The world with the visit counts of each planner (summed over seeds, square-root colour
    scale, unvisited cells white); walls shaded grey, doors outlined in red, and in a world of
    other labels each cell's label written in it. ``true_map``: the map the runs used (None when
    they used different maps: the counts alone). ``axes``: one per planner (created when None)."""
    from matplotlib.colors import PowerNorm
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    planners = list(dict.fromkeys(table["planner"]))
    if axes is None:
        figure = Figure(figsize=(3.6 * len(planners), 3.6), layout="constrained")
        axes = np.atleast_1d(figure.subplots(1, len(planners)))
    labels = None if true_map is None else np.asarray(true_map).reshape(model.rows, model.cols)
    doors = np.empty(0, dtype=np.int64) if true_map is None else door_cells(model, np.asarray(true_map))
    door_share = ""
    for ax, planner in zip(axes, planners):
        where = table.loc[table["planner"] == planner, "true_location"].to_numpy()
        counts = np.bincount(where, minlength=model.n_cells).reshape(model.rows, model.cols)
        image = ax.imshow(np.ma.masked_equal(counts, 0), cmap="viridis",
                          norm=PowerNorm(0.5, vmin=0, vmax=max(1, counts.max())))
        if labels is not None and model.label_names == DOOR_LABELS:
            walls = np.zeros(labels.shape + (4,))
            walls[labels == WALL] = (0.5, 0.5, 0.5, 0.6)
            ax.imshow(walls)
            for cell in doors:
                row, col = divmod(int(cell), model.cols)
                ax.add_patch(Rectangle((col - 0.45, row - 0.45), 0.9, 0.9, fill=False, edgecolor="red", linewidth=2))
            door_share = f", {np.isin(where, doors).mean():.0%} of steps on doors"
        elif labels is not None:
            for (row, col), label in np.ndenumerate(labels):
                ax.text(col, row, model.label_names[label], ha="center", va="center", fontsize=7, color="0.3")
        ax.set(title=f"{planner}{door_share}" + ("" if labels is not None else "\n(a map per seed: not drawn)"),
               xticks=[], yticks=[])
        ax.figure.colorbar(image, ax=ax, shrink=0.8, label="visits")
    return axes[0].figure
