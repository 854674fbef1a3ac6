"""Figures (matplotlib, Agg backend, PNG): trajectories (Fig. 8-10), the action-value map
(Fig. 11), learning curves from TensorBoard logs, and episode animations (GIF, or MP4 with ffmpeg).

matplotlib, imageio and tensorboard are imported lazily, inside the functions that need them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_crowdnav.evaluation.runner import EpisodeRecord, Trajectory
from sb3_crowdnav.sim.actions import N_DIRECTIONS, N_SPEEDS, action_table
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import Robot

ROBOT_COLOR = "#d4a017"
DEFAULT_CURVE_TAGS = ("rollout/success_rate", "rollout/ep_rew_mean")


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
        raise ImportError("figures need matplotlib: pip install matplotlib") from exc
    return plt


def _save(fig, path: str | Path, **kwargs) -> Path:
    """Write ``fig`` as PNG (creating the folder) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, **kwargs)
    _pyplot().close(fig)
    return path


def _as_trajectory(item: EpisodeRecord | Trajectory) -> tuple[Trajectory, str]:
    if isinstance(item, Trajectory):
        return item, ""
    if isinstance(item, EpisodeRecord):
        if item.trajectory is None:
            raise ValueError(f"episode {item.seed} has no trajectory; run it with keep_trajectories=True")
        return item.trajectory, f"{item.outcome}, {item.navigation_time:.2f} s"
    raise TypeError(f"expected an EpisodeRecord or a Trajectory, got {type(item).__name__}")


def _extent(scene: SceneConfig) -> float:
    if scene.scenario == "square_crossing":
        return max(scene.circle_radius, scene.square_width / 2) + 1.0
    return scene.circle_radius + 1.5


def _draw_trajectory(ax, traj: Trajectory, stamp_every: int, cmap) -> None:
    from matplotlib.patches import Circle

    robot, humans = traj.robot, traj.humans
    times = traj.times
    last = len(robot) - 1
    # the last state always; a regular stamp too close to it would print over it
    stamps = [k for k in range(0, last, stamp_every) if last - k >= stamp_every / 2] + [last]
    ax.plot(robot[:, 0], robot[:, 1], color=ROBOT_COLOR, lw=1.2, zorder=2)
    for i in range(humans.shape[1]):
        ax.plot(humans[:, i, 0], humans[:, i, 1], color=cmap(i % 10), lw=0.8, alpha=0.6, zorder=1)
    for k in stamps:
        alpha = 0.25 + 0.75 * k / max(last, 1)  # later states darker, as in the paper's figures
        for i in range(humans.shape[1]):
            h = humans[k, i]
            ax.add_patch(Circle(h[:2], h[4], fc="none", ec=cmap(i % 10), lw=1.0, alpha=alpha, zorder=3))
            ax.text(h[0], h[1], f"{times[k]:.0f}" if stamp_every * traj.scene.time_step >= 1 else f"{times[k]:.1f}",
                    ha="center", va="center", fontsize=5, color=cmap(i % 10), alpha=alpha, zorder=4)
        r = robot[k]
        ax.add_patch(Circle(r[Robot.POS], r[Robot.RADIUS], fc=ROBOT_COLOR, ec="k", lw=0.8, alpha=alpha, zorder=5))
        ax.text(r[0], r[1], f"{times[k]:.0f}" if stamp_every * traj.scene.time_step >= 1 else f"{times[k]:.1f}",
                ha="center", va="center", fontsize=5, color="k", zorder=6)
    goal = robot[0, Robot.GOAL]
    ax.plot(goal[0], goal[1], marker="*", color="red", ms=12, mec="k", zorder=6)
    for i, g in enumerate(traj.human_goals):
        ax.plot(g[0], g[1], marker="x", color=cmap(i % 10), ms=4, alpha=0.6)


def _draw_obstacles(ax, obstacles: Sequence[np.ndarray]) -> None:
    """The racks and walls ((k, 2) vertex arrays), grey, under everything else."""
    from matplotlib.patches import Polygon

    for vertices in obstacles:
        ax.add_patch(Polygon(vertices, closed=True, fc="0.6", ec="0.35", lw=0.6, zorder=0))


def _trajectory_legend(fig, stamp_interval: float, obstacles: bool, ncol: int = 4) -> None:
    """What the marks mean, under the panels (``ncol`` entries per row: 2 under a single panel, so it fits)."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], marker="o", color=ROBOT_COLOR, mec="k", ls="-", label=f"robot, every {stamp_interval:g} s "
               "(number: time [s])"),
        Line2D([], [], marker="o", mfc="none", color="tab:blue", ls="-", label="pedestrian (same numbers)"),
        Line2D([], [], marker="*", color="red", mec="k", ms=10, ls="none", label="robot goal"),
    ]
    if obstacles:
        handles.append(Line2D([], [], marker="s", color="0.6", ls="none", ms=8, label="rack / wall"))
    else:
        handles.append(Line2D([], [], marker="x", color="tab:blue", ls="none", label="pedestrian goal"))
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=7, frameon=False)


def plot_trajectories(episodes: Mapping[str, EpisodeRecord | Trajectory], path: str | Path,
                      stamp_interval: float = 2.0, panel_size: float = 4.0, title: str | None = None) -> Path:
    """One subplot per policy of (usually) the same test episode, circles with time stamps (Fig. 8-10).

    :param episodes: label → record (with trajectory) or trajectory
    :param path: PNG file to write
    :param stamp_interval: time between drawn circles [s]; the last state is always drawn
    """
    if not episodes:
        raise ValueError("plot_trajectories needs at least one episode")
    plt = _pyplot()
    items = [(label, *_as_trajectory(item)) for label, item in episodes.items()]
    n = len(items)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(panel_size * cols, panel_size * rows), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for ax, (label, traj, subtitle) in zip(axes.flat, items, strict=False):
        stamp_every = max(1, round(stamp_interval / traj.scene.time_step))
        _draw_trajectory(ax, traj, stamp_every, cmap)
        _draw_obstacles(ax, traj.obstacles)
        if traj.obstacles:  # the warehouse: the view of the hall
            corners = np.concatenate(traj.obstacles)
            ax.set_xlim(corners[:, 0].min() - 0.3, corners[:, 0].max() + 0.3)
            ax.set_ylim(corners[:, 1].min() - 0.3, corners[:, 1].max() + 0.3)
        else:
            half = _extent(traj.scene)
            ax.set_xlim(-half, half)
            ax.set_ylim(-half, half)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{label}" + (f" ({subtitle})" if subtitle else ""), fontsize=9)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    narrow = cols == 1  # one panel: the legend in two rows
    fig.tight_layout(rect=(0, 0.1 if narrow else 0.06, 1, 1))
    _trajectory_legend(fig, stamp_interval, any(traj.obstacles for _, traj, _ in items), ncol=2 if narrow else 4)
    return _save(fig, path)


def plot_collisions(clips: Mapping[str, tuple[Trajectory, Sequence[float]]], path: str | Path,
                    stamp_interval: float = 0.5, half_width: float = 3.0, panel_size: float = 4.0,
                    title: str | None = None) -> Path:
    """One panel per collision: the end of its episode (a :class:`Trajectory` cut to its last seconds, e.g.
    :attr:`~sb3_crowdnav.evaluation.failures.FailureRecord.clip`) around the contact point, marked with a red cross.

    :param clips: label → (trajectory, contact point (x, y) [m])
    :param path: PNG file to write
    :param stamp_interval: [s] between drawn circles; their numbers count from the clip's start
    :param half_width: [m] each panel shows the contact point ± this
    """
    if not clips:
        raise ValueError("plot_collisions needs at least one clip")
    plt = _pyplot()
    cols = min(len(clips), 3)
    rows = math.ceil(len(clips) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(panel_size * cols, panel_size * rows), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for ax, (label, (traj, (x, y))) in zip(axes.flat, clips.items(), strict=False):
        _draw_trajectory(ax, traj, max(1, round(stamp_interval / traj.scene.time_step)), cmap)
        _draw_obstacles(ax, traj.obstacles)
        ax.plot(x, y, marker="X", color="red", mec="k", ms=14, ls="none", zorder=7)
        for text in ax.texts:  # time stamps of people outside the panel: not drawn beside it
            text.set_clip_on(True)
        ax.set_xlim(x - half_width, x + half_width)
        ax.set_ylim(y - half_width, y + half_width)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(label, fontsize=8)
    for ax in list(axes.flat)[len(clips):]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.1 if cols == 1 else 0.06, 1, 1))
    _trajectory_legend(fig, stamp_interval, any(traj.obstacles for traj, _ in clips.values()), ncol=2 if cols == 1 else 4)
    return _save(fig, path)


# ------------------------------------------------------------------ Fig. 11: action values
def action_value_grid(values: np.ndarray, observation: Mapping[str, np.ndarray], scene: SceneConfig | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrange the 80 action values as (speeds, angles, grid) for a polar heat map.

    :param values: (80,) value of each action (action ``a``: speed ``a // 16``, direction ``a % 16``), or (81,) with the
        stop of ``actions="with_stop"`` last, which has no direction and is left out of the map
    :param observation: one (unbatched) observation; its robot heading and goal fix the world angles
    :return: ``speeds (5,)`` [m/s], ``angles (16,)`` world direction of motion [rad] in [0, 2π)
        sorted ascending, ``grid (5, 16)`` values in the same order
    """
    scene = scene or SceneConfig()
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if values.shape == (N_SPEEDS * N_DIRECTIONS + 1,):  # the stop (speed 0): not a point of the polar map
        values = values[:-1]
    if values.shape != (N_SPEEDS * N_DIRECTIONS,):
        raise ValueError(f"values must have {N_SPEEDS * N_DIRECTIONS} entries, got shape {np.shape(values)}")
    robot = np.asarray(observation["robot"], dtype=np.float64).reshape(-1)
    speeds, directions = action_table(float(robot[Robot.V_PREF]), scene.rotation_range)
    if scene.kinematics == "unicycle":
        base = float(robot[Robot.HEADING])
    else:
        to_goal = robot[Robot.GOAL] - robot[Robot.POS]
        base = float(np.arctan2(to_goal[1], to_goal[0]))
    angles = np.mod(base + directions[:N_DIRECTIONS], 2 * np.pi)
    order = np.argsort(angles)
    grid = values.reshape(N_SPEEDS, N_DIRECTIONS)[:, order]
    return speeds[::N_DIRECTIONS], angles[order], grid


def _edges(centres: np.ndarray, period: float | None = None) -> np.ndarray:
    if len(centres) == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    mids = (centres[1:] + centres[:-1]) / 2
    if period is not None and np.isclose((centres[-1] - centres[0]) + (centres[1] - centres[0]), period):
        first = centres[0] - (centres[1] - centres[0]) / 2
        return np.concatenate([[first], mids, [first + period]])
    return np.concatenate([[2 * centres[0] - mids[0]], mids, [2 * centres[-1] - mids[-1]]])


def action_values_of(model: Any, observation: Mapping[str, np.ndarray]) -> np.ndarray:
    """(80,) values of the actions at one observation from ``model.policy.action_values`` (or ``model.action_values``)."""
    policy = getattr(model, "policy", model)
    fn = getattr(policy, "action_values", None)
    if fn is None:
        raise TypeError(f"{type(model).__name__} has no policy.action_values(observation); "
                        "the value map needs a value-based model such as APGValue")
    batched = {k: np.asarray(v)[None] for k, v in observation.items()}
    return np.asarray(fn(batched)).reshape(-1)


def plot_value_map(model: Any, observation: Mapping[str, np.ndarray], path: str | Path, scene: SceneConfig | None = None,
                   values: np.ndarray | None = None, title: str | None = None) -> np.ndarray:
    """Polar heat map of the value of each of the 80 actions at ``observation`` (Fig. 11).

    Rings are the 5 speeds, sectors the 16 directions drawn at their **world** direction of
    motion (0 = +x, counter-clockwise); the robot's heading and the chosen (best) action are
    marked. ``model`` is anything with ``policy.action_values`` (e.g. an APGValue model); pass
    ``values`` (80,) instead to plot precomputed values. Returns the (80,) values.
    """
    if values is None:
        values = action_values_of(model, observation)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    speeds, angles, grid = action_value_grid(values, observation, scene)
    plt = _pyplot()
    fig = plt.figure(figsize=(5, 5))
    ax = fig.add_subplot(projection="polar")
    r_edges = np.concatenate([[0.0], speeds])
    t_edges = _edges(angles, period=2 * np.pi)
    mesh = ax.pcolormesh(t_edges, r_edges, grid, cmap="viridis", shading="flat")
    fig.colorbar(mesh, ax=ax, pad=0.1, label="R + gamma^(Δt·v_pref)·V(s')")
    best = int(np.argmax(values))
    robot = np.asarray(observation["robot"], dtype=np.float64).reshape(-1)
    i_speed, i_dir = np.unravel_index(int(np.argmax(grid)), grid.shape)
    ax.plot(angles[i_dir], speeds[i_speed] - (speeds[0] / 2), marker="o", color="red", ms=7, mec="w",
            ls="none", label="chosen action (highest value)")
    heading = float(robot[Robot.HEADING])
    ax.annotate("", xy=(heading, speeds[-1]), xytext=(0, 0),
                arrowprops={"arrowstyle": "->", "color": "w", "lw": 1.5})
    from matplotlib.lines import Line2D

    arrow = Line2D([], [], color="0.4", marker=">", ls="-", label="robot heading (rings: speed [m/s])")
    fig.legend(handles=[*ax.get_legend_handles_labels()[0], arrow], loc="lower left", ncol=1, fontsize=7,
               frameon=False)
    fig.subplots_adjust(bottom=0.16)
    ax.set_ylim(0, speeds[-1])
    ax.set_yticks(speeds)
    ax.set_yticklabels([f"{s:.1f}" for s in speeds], fontsize=7)
    ax.set_title(title or f"action values (best: action {best})", fontsize=10, pad=18)
    _save(fig, path, bbox_inches="tight")
    return values


# ------------------------------------------------------------------ learning curves
def _event_dirs(root: Path) -> list[Path]:
    return sorted({p.parent for p in root.rglob("events.out.tfevents*")})


def read_scalars(logdir: str | Path, tags: Sequence[str] = DEFAULT_CURVE_TAGS) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Scalars of one TensorBoard run directory: tag → ``(steps, values)`` (tags not logged are left out)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(logdir), size_guidance={"scalars": 0})
    acc.Reload()
    available = set(acc.Tags().get("scalars", []))
    out = {}
    for tag in tags:
        if tag in available:
            events = acc.Scalars(tag)
            out[tag] = (np.array([e.step for e in events]), np.array([e.value for e in events], dtype=np.float64))
    return out


def find_runs(logdir: str | Path) -> dict[str, Path]:
    """Every directory under ``logdir`` holding TensorBoard event files, labelled by its relative path."""
    root = Path(logdir)
    if not root.exists():
        raise FileNotFoundError(f"no TensorBoard log directory {str(root)!r}")
    return {(str(d.relative_to(root)) if d != root else root.name): d for d in _event_dirs(root)}


def plot_learning_curves(runs: Mapping[str, str | Path] | str | Path, path: str | Path,
                         tags: Sequence[str] = DEFAULT_CURVE_TAGS, smooth: int = 1) -> Path:
    """One subplot per tag, one line per run, from TensorBoard event files (x = environment steps).

    :param runs: label → run directory, or a log root searched for runs (e.g. SB3's ``tensorboard_log``)
    :param smooth: moving-average window (in logged points)
    """
    run_dirs = find_runs(runs) if isinstance(runs, (str, Path)) else {k: Path(v) for k, v in runs.items()}
    data = {label: read_scalars(d, tags) for label, d in run_dirs.items()}
    present = [t for t in tags if any(t in d for d in data.values())]
    if not present:
        raise ValueError(f"none of the tags {list(tags)} is logged in {sorted(map(str, run_dirs.values()))}")
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(present), figsize=(5 * len(present), 3.5), squeeze=False)
    for ax, tag in zip(axes.flat, present, strict=True):
        for label, scalars in data.items():
            if tag not in scalars:
                continue
            steps, values = scalars[tag]
            if smooth > 1 and len(values) >= smooth:
                values = np.convolve(values, np.ones(smooth) / smooth, mode="valid")
                steps = steps[smooth - 1:]
            ax.plot(steps, values, label=label, marker="." if len(steps) < 20 else None)
        ax.set_xlabel("environment steps")
        ax.set_title(tag, fontsize=10)
        ax.grid(alpha=0.3)
    if len(data) > 1:
        axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


# ------------------------------------------------------------------ animations
def render_frames(traj: Trajectory) -> list[np.ndarray]:
    """RGB frames (H, W, 3) of every step of an episode, drawn by the env's renderer."""
    from sb3_crowdnav.envs.rendering import CrowdRenderer

    renderer = CrowdRenderer(traj.scene)
    try:
        pairs = list(zip(traj.robot, traj.humans, strict=True))
        goal = traj.robot[0, Robot.GOAL]
        return [renderer.draw(pairs[: k + 1], traj.human_goals, goal, float(t), obstacles=traj.obstacles)
                for k, t in enumerate(traj.times)]
    finally:
        renderer.close()


def ffmpeg_available() -> bool:
    """Whether MP4 can be written (``imageio_ffmpeg`` with its ffmpeg binary)."""
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # not installed, or no binary found
        return False
    return True


def save_animation(item: EpisodeRecord | Trajectory, path: str | Path, fps: float | None = None) -> Path:
    """Write an episode as an animated GIF (``.gif``) or an MP4 (``.mp4``, needs ``imageio-ffmpeg``).

    ``fps`` defaults to real time (1 / Δt: 4 frames per second).
    """
    traj, _ = _as_trajectory(item)
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"an animation is written as .gif or .mp4, got {str(path)!r}")
    try:
        import imageio.v2 as imageio
    except ImportError as exc:
        raise ImportError("animations need imageio: pip install imageio (or pip install 'sb3_crowdnav[gif]')") from exc
    if suffix == ".mp4" and not ffmpeg_available():
        raise ImportError("MP4 needs ffmpeg through imageio-ffmpeg: pip install imageio-ffmpeg (or write a .gif)")
    fps = fps or 1.0 / traj.scene.time_step
    frames = render_frames(traj)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        imageio.mimsave(path, frames, duration=1000.0 / fps, loop=0)
    else:
        imageio.mimsave(path, frames, fps=fps, macro_block_size=1)
    return path


__all__ = [
    "DEFAULT_CURVE_TAGS",
    "action_value_grid",
    "action_values_of",
    "ffmpeg_available",
    "find_runs",
    "plot_collisions",
    "plot_learning_curves",
    "plot_trajectories",
    "plot_value_map",
    "read_scalars",
    "render_frames",
    "save_animation",
]
