"""Pictures of the observation models (paper Fig. 1) and a rollout animation, in the ego's TRUE
frame (metres, x ahead, y left): grey the scene as it is, colour what the observation holds where
it reports it (under position noise it slides off the truth), from the training's
:func:`observe_with_selection`."""

from __future__ import annotations

import math
import os
import sys
import textwrap
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import igdrivsim.simulator as sim
from igdrivsim.data.scenario import CURRENT_INDEX
from igdrivsim.io import atomic_savefig, atomic_write
from igdrivsim.observation.features import DEFAULT_CONFIG, POSITION_SCALE, ObservationConfig
from igdrivsim.observation.models import (
    PRESET_TITLES,
    CircularFieldOfView,
    ConicFieldOfView,
    GaussianPositionNoise,
    ObservationSetting,
    get_setting,
    perceive_pose,
)
from igdrivsim.observation.observe import observe_with_selection
from igdrivsim.simulator import current_objects
from igdrivsim.simulator.state import thin_roadgraph

# Roadgraph categories for colouring (WOMD tf.Example type codes).
ROAD_CATEGORIES: dict[str, tuple[tuple[int, ...], str]] = {
    "lane centre": ((1, 2, 3), "#4c72b0"),
    "road line": (tuple(range(5, 14)), "#8c8c8c"),
    "road edge": ((14, 15, 16), "#222222"),
    "crosswalk / stop / bump": ((17, 18, 19), "#8172b2"),
}
HIDDEN = "#d0d0d0"
OBSERVED_OBJECT = "#55a868"
EGO = "#c44e52"
FOV = "#dd8452"
MAP_SPACING = 0.5  # metres between a WOMD polyline's points


@dataclass(frozen=True)
class ProfileView:
    """What a training profile's policy observes (a test keeps it equal to the profile's, which
    this layer cannot import)."""

    profile: str
    num_objects: int
    num_roadgraph_points: int
    roadgraph_stride: int  # the observable map keeps every k-th point of each polyline

    def describe(self) -> str:
        """One line: the profile and its observation capacities."""
        stride = self.roadgraph_stride
        which = "every map point" if stride == 1 else f"every {stride}th map point"
        return (f"{self.profile} profile: {self.num_objects} objects, "
                f"{self.num_roadgraph_points:,} nearest road points ({which}, "
                f"{MAP_SPACING * stride:g} m apart)")


PROFILE_VIEWS: dict[str, ProfileView] = {
    "laptop": ProfileView("laptop", 16, 64, 8),  # the default run's drivers
    "paper": ProfileView("paper", 32, 1500, 1),  # the paper's observation
}


@dataclass
class Snapshot:
    """Everything one panel draws (NumPy, ego TRUE frame, metres)."""

    road_xy: np.ndarray  # [R, 2] all valid (cropped) roadgraph points
    obj_xy: np.ndarray  # [O, 2] all valid other objects
    obj_yaw: np.ndarray  # [O]
    obj_size: np.ndarray  # [O, 2] length, width
    obj_seen: np.ndarray  # [O] bool, object is in the observation
    ego_size: tuple[float, float]
    seen_road_xy: np.ndarray  # [N, 2] observed roadgraph points, as the observation reports them
    seen_road_type: np.ndarray  # [N]
    seen_obj_xy: np.ndarray  # [M, 2] observed objects, as the observation reports them
    seen_obj_yaw: np.ndarray  # [M]
    seen_obj_size: np.ndarray  # [M, 2]
    noise_offset: np.ndarray | None  # [2] believed minus true ego position (ego frame), if any


def _to_frame(xy: np.ndarray, origin: np.ndarray, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    d = xy - origin
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)


_observe_jit = jax.jit(observe_with_selection, static_argnums=(1, 4))


def snapshot(state: Any, setting: ObservationSetting | str, episode_key: jax.Array,
             step_key: jax.Array, config: ObservationConfig = DEFAULT_CONFIG,
             stride: int = 1) -> Snapshot:
    """What to draw of ONE simulator state observed under ``setting`` with capacities ``config``
    on the map thinned to every ``stride``-th point (the grey scene keeps the whole map)."""
    setting = get_setting(setting)
    ref = jnp.stack([state.sdc.x[CURRENT_INDEX], state.sdc.y[CURRENT_INDEX]])
    observable = state.replace(roadgraph=thin_roadgraph(state.roadgraph, stride, ref))
    obs, sel = _observe_jit(observable, setting, episode_key, step_key, config)
    obs, sel = jax.tree.map(np.asarray, (obs, sel))
    objs = jax.tree.map(np.asarray, current_objects(state))
    i = int(state.sdc_index)
    ego_xy = np.array([objs.x[i], objs.y[i]], np.float64)
    ego_yaw = float(objs.yaw[i])

    rg = jax.tree.map(np.asarray, state.roadgraph)
    road_xy = _to_frame(rg.xyz[rg.valid, :2].astype(np.float64), ego_xy, ego_yaw)

    others = objs.valid.astype(bool) & (np.arange(objs.x.shape[0]) != i)
    obj_xy = _to_frame(np.stack([objs.x, objs.y], -1)[others].astype(np.float64), ego_xy, ego_yaw)
    seen_slots = sel.object_index[obs.objects_valid]
    seen = np.isin(np.arange(objs.x.shape[0]), seen_slots)

    o = obs.objects[obs.objects_valid]
    r = obs.roadgraph[obs.roadgraph_valid]
    noise = None
    if any(isinstance(m, GaussianPositionNoise) for m in setting.models):
        xy, _ = perceive_pose(setting, jnp.asarray(ego_xy, jnp.float32), jnp.float32(ego_yaw),
                              episode_key, step_key)
        noise = _to_frame(np.asarray(xy, np.float64), ego_xy, ego_yaw)
    return Snapshot(
        road_xy=road_xy,
        obj_xy=obj_xy, obj_yaw=objs.yaw[others] - ego_yaw,
        obj_size=np.stack([objs.length[others], objs.width[others]], -1),
        obj_seen=seen[others],
        ego_size=(float(objs.length[i]), float(objs.width[i])),
        seen_road_xy=r[:, :2] * POSITION_SCALE, seen_road_type=np.argmax(r[:, 4:24], -1),
        seen_obj_xy=o[:, :2] * POSITION_SCALE, seen_obj_yaw=np.arctan2(o[:, 3], o[:, 2]),
        seen_obj_size=np.stack([objs.length[seen_slots], objs.width[seen_slots]], -1),
        noise_offset=noise,
    )


def _box(ax, xy, yaw, size, **kw) -> None:
    from matplotlib.patches import Polygon  # heavy: only when drawing

    length, width = size
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    ax.add_patch(Polygon(corners @ np.array([[c, s], [-s, c]]) + xy, closed=True, **kw))


def _draw_fov(ax, setting: ObservationSetting) -> None:
    from matplotlib.patches import Circle, Wedge  # heavy: only when drawing

    for m in setting.models:
        for fill in (True, False):  # translucent area under everything, outline on top
            style = (dict(facecolor=FOV, alpha=0.15, lw=0, zorder=1) if fill else
                     dict(facecolor="none", edgecolor=FOV, lw=1.3, ls="--", zorder=6))
            if isinstance(m, ConicFieldOfView):
                half = math.degrees(m.angle) / 2
                ax.add_patch(Wedge((0, 0), m.radius, -half, half, **style))
            elif isinstance(m, CircularFieldOfView):
                ax.add_patch(Circle((0, 0), m.radius, **style))


def draw_layers(ax, snap: Snapshot, setting: ObservationSetting, marker: float = 1.0) -> None:
    """The scene (grey), the field of view, the observation (colour) and the ego on ``ax``."""
    ax.scatter(snap.road_xy[:, 0], snap.road_xy[:, 1], s=1.0 * marker, c=HIDDEN, lw=0, zorder=0,
               rasterized=True)
    for xy, yaw, size, seen in zip(snap.obj_xy, snap.obj_yaw, snap.obj_size, snap.obj_seen,
                                   strict=True):
        _box(ax, xy, yaw, size, facecolor="none", edgecolor="#9a9a9a",
             ls="-" if seen else ":", lw=0.8, zorder=2)
    _draw_fov(ax, setting)
    size = 2.5 if len(snap.seen_road_xy) > 300 else 6.0  # a sparse observation: larger dots
    for types, colour in ROAD_CATEGORIES.values():
        pick = np.isin(snap.seen_road_type, types)
        ax.scatter(snap.seen_road_xy[pick, 0], snap.seen_road_xy[pick, 1], s=size * marker,
                   c=colour, lw=0, zorder=3, rasterized=True)
    for xy, yaw, size in zip(snap.seen_obj_xy, snap.seen_obj_yaw, snap.seen_obj_size, strict=True):
        _box(ax, xy, yaw, size, facecolor=OBSERVED_OBJECT, edgecolor="#2d6a3e", alpha=0.85,
             lw=0.8, zorder=4)
    _box(ax, (0.0, 0.0), 0.0, snap.ego_size, facecolor=EGO, edgecolor="#7a1f22", lw=0.8,
         alpha=0.8, zorder=5)
    if snap.noise_offset is not None:
        # the observation is relative to the believed position: draw it (dashed) and the offset
        off = snap.noise_offset
        _box(ax, off, 0.0, snap.ego_size, facecolor="none", edgecolor=EGO, ls="--", lw=1.0,
             zorder=5)
        ax.annotate("", xy=off, xytext=(0, 0), zorder=6,
                    arrowprops=dict(arrowstyle="->", color=EGO, lw=1.2))


def panel_note(snap: Snapshot, width: int = 44) -> str:
    """What the panel's observation holds, in lines of at most ``width`` characters."""
    parts = [f"seen: {int(snap.obj_seen.sum())}/{len(snap.obj_seen)} objects, "
             f"{len(snap.seen_road_xy):,} road points"]
    if snap.noise_offset is not None:
        parts.append(f"believed ego {np.hypot(*snap.noise_offset):.1f} m off (dashed box)")
    return "\n".join(line for part in parts for line in textwrap.wrap(part, width))


def draw_panel(ax, snap: Snapshot, setting: ObservationSetting, title: str | None = None,
               view: float = 30.0) -> None:
    """One observation panel on ``ax``, zoomed in an inset under a small field of view."""
    draw_layers(ax, snap, setting)
    ax.set_xlim(-0.5 * view, 1.5 * view)  # more room ahead of the ego than behind
    ax.set_ylim(-0.75 * view, 0.75 * view)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_title(title or setting.name, fontsize=9)
    ax.text(0.01, 0.01, panel_note(snap), transform=ax.transAxes, fontsize=6, va="bottom",
            color="#333333", bbox=dict(facecolor="white", alpha=0.8, lw=0, pad=1.5), zorder=7)
    radii = [m.radius for m in setting.models
             if isinstance(m, (CircularFieldOfView, ConicFieldOfView))]
    if radii and min(radii) < view / 3:  # zoom on the smallest field of view
        sub = ax.inset_axes([0.58, 0.52, 0.41, 0.46])
        draw_layers(sub, snap, setting, marker=4.0)
        half = min(radii) + 3.0
        sub.set_xlim(-half, half)
        sub.set_ylim(-half * 0.85, half * 0.85)
        sub.set_aspect("equal")
        sub.set_xticks([])
        sub.set_yticks([])
        sub.text(0.03, 0.97, f"zoom ±{half:.0f} m", transform=sub.transAxes, fontsize=6,
                 va="top", color="#333333")
        for side in sub.spines.values():
            side.set_edgecolor("#555555")


def legend_handles() -> list:
    """Legend entries shared by every panel."""
    from matplotlib.lines import Line2D  # heavy: only when drawing
    from matplotlib.patches import Patch  # heavy: only when drawing

    dots = [Line2D([], [], ls="", marker="o", ms=4, color=c, label=f"observed {n}")
            for n, (_, c) in ROAD_CATEGORIES.items()]
    return dots + [
        Line2D([], [], ls="", marker="o", ms=4, color=HIDDEN, label="road point not observed"),
        Patch(facecolor=OBSERVED_OBJECT, edgecolor="#2d6a3e", label="observed object"),
        Patch(facecolor="none", edgecolor="#9a9a9a", ls=":", label="hidden object (true pose)"),
        Patch(facecolor=EGO, edgecolor="#7a1f22", label="ego (SDC)"),
        Patch(facecolor=FOV, alpha=0.3, edgecolor=FOV, ls="--", label="field of view"),
    ]


X_LABEL, Y_LABEL = "x, ahead of the ego (m)", "y, left of the ego (m)"


def observation_figure(state: Any, settings: list[str], key: jax.Array, view: float = 30.0,
                       source: str | None = None):
    """Fig. 1: per profile of :data:`PROFILE_VIEWS` a block of one panel per setting on the same
    (unbatched, full-map) state; ``source`` is said under the title."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing

    views = list(PROFILE_VIEWS.values())
    ncols = 3 if len(settings) > 2 else len(settings)
    nrows = math.ceil(len(settings) / ncols)
    fig = plt.figure(figsize=(3.3 * ncols, (2.75 * nrows + 0.35) * len(views) + 1.3),
                     layout="constrained")
    episode_key, step_key = jax.random.split(key)
    for sub, profile in zip(fig.subfigures(len(views), 1, squeeze=False)[:, 0], views, strict=True):
        axes = sub.subplots(nrows, ncols, squeeze=False)
        for i, (ax, name) in enumerate(zip(axes.flat, settings, strict=False)):
            setting = get_setting(name)
            config = ObservationConfig(profile.num_objects, profile.num_roadgraph_points)
            snap = snapshot(state, setting, episode_key, step_key, config, profile.roadgraph_stride)
            draw_panel(ax, snap, setting, PRESET_TITLES.get(setting.name, setting.name), view)
            if i % ncols == 0:
                ax.set_ylabel(Y_LABEL, fontsize=7)
            if i + ncols >= len(settings):  # the lowest panel of its column
                ax.set_xlabel(X_LABEL, fontsize=7)
        for ax in list(axes.flat)[len(settings):]:
            ax.axis("off")
        sub.suptitle(profile.describe(), fontsize=10, fontweight="bold")
    title = ("What each profile's policy observes, in the ego's frame (colour: in the "
             "observation; grey: the true scene)")
    fig.suptitle(f"{title}\n{source}" if source else title, fontsize=11)
    fig.legend(handles=legend_handles(), loc="outside lower center",
               ncol=5 if ncols >= 3 else 2 * ncols, fontsize=7, frameon=False)
    return fig


def write_observation_figure(state: Any, out_dir: str | os.PathLike, settings: list[str],
                             key: jax.Array, view: float = 30.0, source: str | None = None
                             ) -> list[str]:
    """Write ``out_dir/fig1_observations.{pdf,png}``; returns the paths."""
    import matplotlib.pyplot as plt  # heavy: only when drawing

    fig = observation_figure(state, settings, key, view, source=source)
    try:
        return [os.fspath(atomic_savefig(fig, os.path.join(out_dir, f"fig1_observations.{ext}"),
                                         dpi=200)) for ext in ("pdf", "png")]
    finally:
        plt.close(fig)


def expert_states(state: Any, num_steps: int = 80) -> list[Any]:
    """The states of a discretised-expert rollout from an (unbatched) reset state, step by step."""
    params = sim.SimParams()

    @jax.jit
    def advance(s):
        a = sim.undiscretize(sim.discretize(sim.expert_action(s, params)))
        return sim.step(s, a, params)

    states = [state]
    for _ in range(num_steps):
        states.append(advance(states[-1]))
    return states


def write_rollout_animation(states: list[Any], setting: ObservationSetting | str,
                            path: str | os.PathLike, key: jax.Array, view: float = 30.0,
                            every: int = 1, progress: bool = True) -> str:
    """A GIF of ``states`` with what ``setting`` observes highlighted; written atomically."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing
    from matplotlib.animation import PillowWriter  # heavy: only when drawing
    setting = get_setting(setting)
    episode_key, step_root = jax.random.split(key)
    title = PRESET_TITLES.get(setting.name, setting.name)
    fig, ax = plt.subplots(figsize=(5.2, 4.2))
    writer = PillowWriter(fps=10)

    def write(tmp: os.PathLike) -> None:
        with writer.saving(fig, tmp, dpi=110):
            for s in tqdm(states[::every], desc=f"rollout {setting.name}", unit="frame",
                          file=sys.stderr, disable=not progress):
                ax.clear()
                t = int(s.timestep)
                snap = snapshot(s, setting, episode_key, jax.random.fold_in(step_root, t))
                draw_panel(ax, snap, setting, f"{title}  (step {t}, t={t / 10:.1f} s)", view)
                fig.tight_layout()
                writer.grab_frame()

    try:
        atomic_write(path, write, suffix=".gif")  # a GIF whatever the name
    finally:
        plt.close(fig)
    return os.fspath(path)
