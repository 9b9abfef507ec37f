"""Figures (matplotlib). Functions build ``matplotlib.figure.Figure`` objects directly, without
pyplot's global state, so they work the same from the CLI (saved as PNG, no display needed)
and in a notebook (``display(fig)`` or a figure as a cell's last expression)."""

from __future__ import annotations

import re
from importlib.util import find_spec
from pathlib import Path

import matplotlib.colors
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from . import arguments
from .belief import Belief
from .errors import InvalidOptionError, MissingDependencyError, ModelError
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


DOOR_COLOURS = {"free": "white", "wall": "#404040", "open_door": "tab:green",
                "closed_door": "tab:red"}  # the palette of door-world labels, in every figure and animation
#: a cell the belief knows nothing about (uniform over the labels): a blue-grey, neither free's white nor a wall's grey
UNKNOWN_COLOUR = "#8fa3bf"
UNKNOWN_NAME = "unknown (uniform belief)"


def label_colours(model: GridModel) -> np.ndarray:
    """(K, 3) RGB per label, the one palette of every map figure: :data:`DOOR_COLOURS` for
    door-world labels, matplotlib's C0, C1, ... otherwise."""
    door = set(model.label_names) == set(DOOR_COLOURS)
    return np.array([matplotlib.colors.to_rgb(DOOR_COLOURS[name] if door else f"C{k}")
                     for k, name in enumerate(model.label_names)])


def confidence(maps: np.ndarray) -> np.ndarray:
    """How sure a map belief is of each cell's most likely label, in [0, 1]:
    ``c_i = (max_k P(m_i = k) - 1/K) / (1 - 1/K)``, 0 for a uniform belief, 1 for a certain one.
    maps (..., N, K) -> (..., N). Cost O(N K)."""
    labels = maps.shape[-1]
    return np.clip((maps.max(axis=-1) - 1.0 / labels) * (labels / (labels - 1.0)), 0.0, 1.0)


def belief_colours(model: GridModel, maps: np.ndarray) -> np.ndarray:
    """The colour of each cell of a map belief: its most likely label's colour (:func:`label_colours`)
    blended towards :data:`UNKNOWN_COLOUR` as its :func:`confidence` falls,
    ``rgb_i = c_i colour(argmax_k P(m_i = k)) + (1 - c_i) unknown``; so an unknown cell is blue-grey
    whatever its label's colour, never free's white. maps (..., N, K) -> (..., N, 3). Cost O(N K)."""
    maps = np.asarray(maps, dtype=float)
    sure = confidence(maps)[..., None]
    unknown = np.asarray(matplotlib.colors.to_rgb(UNKNOWN_COLOUR))
    return sure * label_colours(model)[np.argmax(maps, axis=-1)] + (1.0 - sure) * unknown


def label_marks(ax: Axes, model: GridModel, labels=None, unknown: bool = True) -> None:
    """Legend entries (empty square marks) for the labels (``labels``: the indices to list, default
    all) in the colours of :func:`label_colours`, and for the unknown colour (``unknown``)."""
    colours = label_colours(model)
    for k in range(model.n_labels) if labels is None else labels:
        ax.scatter([], [], marker="s", s=60, color=colours[k], edgecolor="black", linewidth=0.5,
                   label=model.label_names[k])
    if unknown:
        ax.scatter([], [], marker="s", s=60, color=UNKNOWN_COLOUR, edgecolor="black", linewidth=0.5,
                   label=UNKNOWN_NAME)


def plot_belief(model: GridModel, belief: Belief, true_map: np.ndarray | None = None,
                true_location: int | None = None) -> Figure:
    """The location and the map of one belief, drawn on the grid.

    Corridors (one row): bars of P(L_t = i) and stacked bars of P(m_i = k) per label. 2D worlds:
    an image of P(L_t) and an image of the map belief, each cell in its most likely label's colour
    blended towards blue-grey as it is uncertain (:func:`belief_colours`). ``true_map`` (N,) and
    ``true_location`` are marked when given (dots on the cells whose most likely label is wrong, a
    star on the robot); every mark is in a legend. A belief of another model's size
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
    colours = label_colours(model)
    if model.rows == 1:
        ax_loc.bar(cells, belief.location, color="tab:purple")
        ax_loc.set(xlabel="cell", ylabel="P(location)", ylim=(0, 1), title=f"location at t = {belief.t}")
        bottom = np.zeros(model.n_cells)
        for k, name in enumerate(model.label_names):
            ax_map.bar(cells, belief.map[:, k], bottom=bottom, label=name, color=colours[k], edgecolor="black",
                       linewidth=0.4)
            bottom += belief.map[:, k]
        ax_map.set(xlabel="cell", ylabel="P(label)", ylim=(0, 1), title="map marginals")
        if true_location is not None:
            ax_loc.plot([true_location], [1.0], marker="*", color="black", markersize=12, clip_on=False,
                        linestyle="none", label="true location")
            ax_loc.legend(loc="upper right", fontsize="x-small")
        if wrong is not None:
            ax_map.plot(wrong, np.full(len(wrong), 1.02), "v", color="black", clip_on=False, label="wrong")
        ax_map.legend(loc="upper right", fontsize="x-small", ncols=min(model.n_labels + 1, 4))
        ax_loc.set_xticks(cells)
        ax_map.set_xticks(cells)
        return fig
    shape = model.shape
    image = ax_loc.imshow(belief.location.reshape(shape), cmap="magma", vmin=0, interpolation="nearest")
    fig.colorbar(image, ax=ax_loc, fraction=0.046, label="P(location)")
    ax_loc.set(title=f"location at t = {belief.t}", xlabel="column", ylabel="row")
    ax_map.imshow(belief_colours(model, belief.map).reshape(*shape, 3), interpolation="nearest")
    ax_map.set(title="map belief (blue-grey: uncertain)", xlabel="column", ylabel="row")
    label_marks(ax_map, model)
    if true_location is not None:
        row, col = divmod(int(true_location), model.cols)
        ax_loc.plot(col, row, marker="*", color="cyan", markersize=12, linestyle="none", label="true location")
        ax_loc.legend(loc="upper left", fontsize="x-small", framealpha=0.6)
    if wrong is not None:
        rows, cols = np.divmod(wrong, model.cols)
        ax_map.plot(cols, rows, ".", color="black", markersize=4, linestyle="none", label="most likely label wrong")
    ax_map.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="x-small")
    return fig


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
    label_marks(ax, model, np.unique(labels), unknown=False)
    if start:
        row, col = divmod(model.start, model.cols)
        ax.plot(col, row, marker="*", color="tab:blue", markersize=12, linestyle="none", label="start")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="small")
    ax.set(title=title or f"{model.rows} x {model.cols} floor", xlabel="column", ylabel="row")
    return fig


ANIMATION_FORMATS = (".gif", ".mp4")
MP4_HINT = "writing MP4 needs imageio and imageio-ffmpeg: pip install imageio imageio-ffmpeg (or write a .gif)"


def animation_frames(steps: int, every: int) -> np.ndarray:
    """The steps an animation shows: 0, every, 2 every, ... and always the last, T - 1."""
    frames = np.arange(0, steps, every)
    return frames if frames[-1] == steps - 1 else np.append(frames, steps - 1)


def animate(model: GridModel, trajectory: Trajectory, path: str | Path, *, true_locations=None, true_maps=None,
            every: int = 1, fps: float = 12.0, dpi: int = 80, title: str = "", first_step: int = 0) -> Path:
    """Write an animation of a run's beliefs over time: a GIF (``.gif``, with pillow) or an MP4
    (``.mp4``, with imageio and imageio-ffmpeg where installed; :class:`MissingDependencyError` otherwise).

    One frame per ``every`` steps (and the last step, :func:`animation_frames`), ``fps`` frames per
    second. Panels: P(L_t) on a log scale (1e-4 to 1); the map belief in the palette of
    :func:`belief_colours` (the most likely label's colour, blue-grey where uncertain); with
    ``true_maps`` ((N,), or (T, N) for a world that changes) the true map and, with
    ``true_locations`` (T,), the true path so far. The robot's most likely cell is circled in the
    belief panels and its true cell starred in every panel; a legend names every mark. Corridors are
    drawn as one-row images. ``first_step``: the step number of the trajectory's first belief, for the frames' step counter
    (a stream resumed from a checkpoint). Returns the path (its directory created).

    The figure (axes, titles, colour bar, legend) is drawn once by matplotlib; each frame is that
    background with the cells painted in by numpy and the marks and step counter drawn by PIL
    (:class:`_Scene`): 500 frames of a 32 x 32 run with its true map took 7 s as a GIF or an MP4 on a
    2-core machine at load 7, about 14 ms a frame, where a matplotlib redraw of the images alone took
    70-90 ms. Memory: a GIF holds its frames, one byte per pixel each, until written; an MP4 streams.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ANIMATION_FORMATS:
        raise InvalidOptionError(f"animation {path}: the file name must end in .gif or .mp4")
    if suffix == ".mp4" and (find_spec("imageio") is None or find_spec("imageio_ffmpeg") is None):
        raise MissingDependencyError(f"animation {path}: {MP4_HINT}")
    steps, cells, labels = trajectory.n_steps, model.n_cells, model.n_labels
    if trajectory.location.shape != (steps, cells) or trajectory.map.shape != (steps, cells, labels) or not steps:
        raise ModelError(f"a trajectory of location {trajectory.location.shape} and map {trajectory.map.shape} "
                         f"does not fit {model} (expected (T, {cells}) and (T, {cells}, {labels}), T >= 1)")
    every = arguments.integer("every", every, minimum=1, error=InvalidOptionError)
    fps = arguments.real("fps", fps, low=0.0, low_open=True, high=100.0, error=InvalidOptionError)
    dpi = arguments.integer("dpi", dpi, minimum=20, maximum=400, error=InvalidOptionError)
    first_step = arguments.integer("first_step", first_step, minimum=0, error=InvalidOptionError)
    truth_path = _true_locations(true_locations, steps, cells)
    truth_maps = _true_maps(true_maps, model, steps)
    frames = animation_frames(steps, every)
    path.parent.mkdir(parents=True, exist_ok=True)
    scene = _Scene(model, trajectory, truth_path, truth_maps, dpi, title, first_step)
    if suffix == ".gif":
        _write_gif(path, scene, frames, fps)
    else:
        _write_mp4(path, (scene.frame(t) for t in frames), fps)
    return path


def _true_locations(locations, steps: int, cells: int) -> np.ndarray | None:
    if locations is None:
        return None
    locations = np.asarray(locations)
    if locations.shape != (steps,) or locations.dtype.kind not in "iu" or locations.min() < 0 or \
            locations.max() >= cells:
        raise ModelError(f"true_locations must be ({steps},) cell indices in 0..{cells - 1}, got "
                         f"{locations.dtype} {locations.shape}")
    return locations


def _true_maps(maps, model: GridModel, steps: int) -> np.ndarray | None:
    if maps is None:
        return None
    maps = np.asarray(maps)
    if maps.shape == (model.n_cells,):
        maps = np.broadcast_to(maps, (steps, model.n_cells))
    if maps.shape != (steps, model.n_cells) or maps.dtype.kind not in "iu" or maps.min() < 0 or \
            maps.max() >= model.n_labels:
        raise ModelError(f"true_maps must be ({model.n_cells},) or ({steps}, {model.n_cells}) labels in "
                         f"0..{model.n_labels - 1}, got {maps.dtype} {maps.shape}")
    return maps


class _Scene:
    """The animation's figure, drawn once by matplotlib (axes, titles, colour bar, legend); a frame is
    that background with the panels' cells painted in by numpy (nearest-neighbour, into the pixel box
    of each axis) and the marks, path and step counter drawn by PIL: a few milliseconds a frame,
    against tens for a matplotlib redraw of the images."""

    LIKELY, TRUE, PATH = "lime", "cyan", "tab:blue"  # the marks' colours, here and in the legend

    def __init__(self, model: GridModel, trajectory: Trajectory, true_locations, true_maps, dpi: int, title: str,
                 first_step: int = 0):
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.colors import LogNorm

        self.model, self.trajectory = model, trajectory
        self.true_locations, self.true_maps, self.first_step = true_locations, true_maps, first_step
        corridor = model.rows == 1
        panels = 3 if true_maps is not None else 2
        width = 3.4 if corridor else min(5.0, max(2.4, 2.9 * model.cols / model.rows))
        height = 0.5 if corridor else width * model.rows / model.cols
        fig = Figure(figsize=(panels * (width + 0.35) + 0.3, height + 1.6), dpi=dpi, layout="constrained")
        canvas = FigureCanvasAgg(fig)
        axes = fig.subplots(1, panels)
        low = min(1e-4, 0.1 / model.n_cells)
        self.norm, self.cmap = LogNorm(low, 1.0, clip=True), colormaps["magma"]
        aspect = "auto" if corridor else "equal"
        location = axes[0].imshow(np.full(model.shape, low), cmap=self.cmap, norm=self.norm, aspect=aspect)
        fig.colorbar(location, ax=axes[0], fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
        titles = ["P(location), log scale", "map belief"]
        if true_maps is not None:
            titles.append("true map" + (" and path" if true_locations is not None else ""))
        for ax, text in zip(axes, titles):
            if ax is not axes[0]:
                ax.imshow(np.ones((*model.shape, 3)), aspect=aspect)
            ax.set_title(text, fontsize=8)
            ax.set(xticks=[], yticks=[])
        # the legend's marks, drawn on the frames by PIL in the same colours and shapes
        axes[0].plot([], [], "o", markerfacecolor="none", markeredgecolor=self.LIKELY, markeredgewidth=1.5,
                     label="most likely cell")
        if true_locations is not None:
            axes[0].plot([], [], "*", markersize=9, color=self.TRUE, markeredgecolor="black", markeredgewidth=0.5,
                         label="true cell")
            if true_maps is not None:
                axes[0].plot([], [], "-", color=self.PATH, linewidth=1.5, label="true path")
        label_marks(axes[1], model)
        handles, names = [], []
        for ax in axes[:2]:
            more, texts = ax.get_legend_handles_labels()
            handles += more
            names += texts
        fig.legend(handles, names, loc="outside lower center", ncols=min(len(names), 4), fontsize=7, frameon=False)
        fig.suptitle(title or " ", fontsize=9)
        canvas.draw()
        self.background = np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[..., :3])
        self.boxes = [self._box(ax, self.background.shape[0]) for ax in axes]
        self.palette = (np.round(255 * label_colours(model)).astype(np.uint8),
                        np.round(255 * np.asarray(matplotlib.colors.to_rgb(UNKNOWN_COLOUR))).astype(np.uint8))
        self.cell = self.boxes[0][2] / model.cols  # pixels per cell (width)
        self.font = _font(max(10, dpi // 6))

    def _box(self, ax: Axes, height: int) -> tuple[int, int, int, int, np.ndarray, np.ndarray]:
        """``(x0, y0, w, h, rows, cols)``: the axis' pixel box (top-left origin) and, for every pixel
        row and column in it, the grid row and column it shows."""
        extent = ax.get_window_extent()
        x0, x1 = int(round(extent.x0)) + 1, int(round(extent.x1)) - 1  # inside the axis' frame line
        y0, y1 = height - int(round(extent.y1)) + 1, height - int(round(extent.y0)) - 1
        w, h = x1 - x0, y1 - y0
        rows = np.minimum((np.arange(h) + 0.5) * self.model.rows // h, self.model.rows - 1).astype(np.intp)
        cols = np.minimum((np.arange(w) + 0.5) * self.model.cols // w, self.model.cols - 1).astype(np.intp)
        return x0, y0, w, h, rows, cols

    def _paint(self, pixels: np.ndarray, panel: int, colours: np.ndarray) -> None:
        """Paint (N, 3) uint8 cell colours into panel ``panel``'s box."""
        x0, y0, w, h, rows, cols = self.boxes[panel]
        grid = colours.reshape(*self.model.shape, 3)
        pixels[y0:y0 + h, x0:x0 + w] = grid.take(rows, axis=0).take(cols, axis=1)

    def _centre(self, panel: int, cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x0, y0, w, h, _, _ = self.boxes[panel]
        row, col = np.divmod(cell, self.model.cols)
        return x0 + (col + 0.5) * w / self.model.cols, y0 + (row + 0.5) * h / self.model.rows

    def frame(self, t: int):
        """The (H, W, 3) uint8 pixels of step ``t`` as a PIL image."""
        from PIL import Image, ImageDraw

        model, trajectory = self.model, self.trajectory
        pixels = self.background.copy()
        self._paint(pixels, 0, self.cmap(self.norm(trajectory.location[t]), bytes=True)[:, :3])
        self._paint(pixels, 1, np.round(255 * belief_colours(model, trajectory.map[t])).astype(np.uint8))
        if self.true_maps is not None:
            self._paint(pixels, 2, self.palette[0][self.true_maps[t]])
        image = Image.fromarray(pixels)
        draw = ImageDraw.Draw(image)
        radius = max(3.0, 0.8 * self.cell)
        rgb = {name: tuple(round(255 * c) for c in matplotlib.colors.to_rgb(name))
               for name in (self.LIKELY, self.TRUE, self.PATH)}
        for panel in (0, 1):
            x, y = self._centre(panel, np.argmax(trajectory.location[t]))
            draw.ellipse((x - radius, y - radius, x + radius, y + radius), outline=rgb[self.LIKELY], width=2)
        if self.true_locations is not None:
            if self.true_maps is not None and t > 0:
                xs, ys = self._centre(2, self.true_locations[:t + 1])
                draw.line(list(zip(xs.tolist(), ys.tolist())), fill=rgb[self.PATH], width=2)
            for panel in range(len(self.boxes)):
                x, y = self._centre(panel, self.true_locations[t])
                draw.polygon(_star(x, y, radius), fill=rgb[self.TRUE], outline=(0, 0, 0))
        draw.text((6, 4), f"step {self.first_step + t} of {self.first_step + trajectory.n_steps - 1}", fill=(0, 0, 0),
                  font=self.font)
        return image


def _star(x: float, y: float, radius: float) -> list[tuple[float, float]]:
    """The ten corners of a five-pointed star centred on (x, y), point up."""
    angles = -np.pi / 2 + np.arange(10) * np.pi / 5
    lengths = np.where(np.arange(10) % 2 == 0, radius, 0.45 * radius)
    return list(zip((x + lengths * np.cos(angles)).tolist(), (y + lengths * np.sin(angles)).tolist()))


def _font(size: int):
    """PIL's own font at ``size`` pixels (its scalable default where FreeType is built in)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, ImportError, OSError):  # a pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _write_gif(path: Path, scene: _Scene, frames: np.ndarray, fps: float) -> None:
    """The frames as one looping GIF, every frame in one palette of 256 colours made from the first
    and the last frame (the map as it starts and as it is learned); one palette costs less than a
    palette per frame and does not flicker."""
    from PIL import Image

    first, last = np.asarray(scene.frame(frames[0])), np.asarray(scene.frame(frames[-1]))
    palette = Image.fromarray(np.concatenate([first, last])).quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    images = [scene.frame(t).quantize(palette=palette, dither=Image.Dither.NONE) for t in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)


def _write_mp4(path: Path, frames, fps: float) -> None:
    """Frames as an H.264 MP4 (imageio's ffmpeg writer), streamed: one frame in memory at a time;
    each cut to even sides, as the codec needs."""
    import imageio.v2 as imageio

    with imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=2) as writer:
        for image in frames:
            pixels = np.asarray(image)
            writer.append_data(pixels[:pixels.shape[0] // 2 * 2, :pixels.shape[1] // 2 * 2])

def slug(text: str) -> str:
    """A file-name-safe version of an estimator label."""
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def save(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG (creating the directory); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
