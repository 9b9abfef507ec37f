"""Figures for exploration runs (matplotlib, no pyplot state: they work on any backend).

Both take the long table of :func:`onlinemap.studies.exploration.compare_planners` (columns ``planner``,
``seed``, ``t``, ``map_error``, ``door_error``, ``true_location``, ...).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from onlinemap.model import CLOSED_DOOR, DOOR_LABELS, OPEN_DOOR, WALL, GridModel, door_cells

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


UNVISITED = "0.82"  # the colour of cells no run visited (light grey: not the page's white)


def plot_visits(model: GridModel, true_map, table: pd.DataFrame, axes=None) -> "Figure":
    """The world with the visit counts of each planner (summed over seeds), every panel on one
    square-root colour scale with one colour bar, so panels compare; cells never visited are light
    grey. With the runs' map (``true_map``; None when they used different maps: the counts alone):
    walls hatched and doors outlined in the colours of :func:`onlinemap.plots.label_colours` (open
    doors green, closed doors red, as the map has them) in a door world, with a legend; in a world of other
    labels each cell's label is written in it. ``axes``: one per planner (created when None)."""
    from matplotlib import colormaps
    from matplotlib.colors import PowerNorm
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch, Rectangle

    from onlinemap.plots import label_colours

    planners = list(dict.fromkeys(table["planner"]))
    if axes is None:
        figure = Figure(figsize=(3.3 * len(planners) + 1.2, 4.0), layout="constrained")
        axes = np.atleast_1d(figure.subplots(1, len(planners)))
    figure = axes[0].figure
    counts = {planner: np.bincount(table.loc[table["planner"] == planner, "true_location"].to_numpy(),
                                   minlength=model.n_cells).reshape(model.rows, model.cols) for planner in planners}
    norm = PowerNorm(0.5, vmin=0, vmax=max(1, *(c.max() for c in counts.values())))  # one scale for every panel
    cmap = colormaps["viridis"].with_extremes(bad=UNVISITED)
    labels = None if true_map is None else np.asarray(true_map).reshape(model.rows, model.cols)
    door_world = labels is not None and model.label_names == DOOR_LABELS
    doors = door_cells(model, np.asarray(true_map)) if door_world else np.empty(0, dtype=np.int64)
    colours = label_colours(model)
    for ax, planner in zip(axes, planners):
        image = ax.imshow(np.ma.masked_equal(counts[planner], 0), cmap=cmap, norm=norm)
        title = planner
        if door_world:
            for (row, col), label in np.ndenumerate(labels):
                if label == WALL:
                    ax.add_patch(Rectangle((col - 0.5, row - 0.5), 1, 1, fill=False, hatch="////",
                                           edgecolor=colours[WALL], linewidth=0))
            for cell in doors:
                row, col = divmod(int(cell), model.cols)
                ax.add_patch(Rectangle((col - 0.45, row - 0.45), 0.9, 0.9, fill=False, linewidth=2,
                                       edgecolor=colours[labels.flat[cell]]))
            where = table.loc[table["planner"] == planner, "true_location"].to_numpy()
            title += f", {np.isin(where, doors).mean():.0%} of steps on doors"
        elif labels is not None:
            for (row, col), label in np.ndenumerate(labels):
                ax.text(col, row, model.label_names[label], ha="center", va="center", fontsize=7, color="0.3")
        ax.set(title=title if labels is not None else f"{planner}\n(a map per seed: not drawn)",
               xticks=[], yticks=[])
    figure.colorbar(image, ax=list(axes), shrink=0.8, label="visits (all seeds)")
    legend = [Patch(facecolor=UNVISITED, edgecolor="0.5", label="never visited")]
    if door_world:
        legend += [Patch(fill=False, hatch="////", edgecolor=colours[WALL], label="wall")]
        legend += [Patch(fill=False, edgecolor=colours[door], linewidth=2, label=model.label_names[door])
                   for door in (OPEN_DOOR, CLOSED_DOOR) if np.any(labels == door)]
    figure.legend(handles=legend, loc="outside lower center", ncol=len(legend), fontsize=8, frameon=False)
    return figure
