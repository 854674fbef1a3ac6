"""Matplotlib drawing of an episode: robot, pedestrians, goals, trails and the time."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import Robot

ROBOT_COLOR = "#d4a017"
HUMAN_CMAP = "tab10"


class CrowdRenderer:
    """Draws into one figure; ``draw`` returns an RGB array (H, W, 3) uint8."""

    def __init__(self, scene: SceneConfig, human: bool = False, size: float = 6.0) -> None:
        try:
            import matplotlib

            if not human:
                matplotlib.use("Agg", force=False)
            import matplotlib.pyplot as plt
        except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
            raise ImportError("rendering needs matplotlib: pip install matplotlib") from exc
        self.plt = plt
        self.scene = scene
        self.human = human
        self.fig, self.ax = plt.subplots(figsize=(size, size), dpi=80)
        if human:
            plt.ion()
            plt.show(block=False)

    def draw(self, trajectory, human_goals: np.ndarray, robot_goal: np.ndarray, time: float,
             obstacles: Sequence[np.ndarray] = (), route: np.ndarray | None = None,
             standing: np.ndarray | None = None, unseen: np.ndarray | None = None) -> np.ndarray:
        """One frame. The warehouse adds its ``obstacles`` ((k, 2) polygons, which also set the view), the robot's
        ``route`` (n, 2) and which pickers are ``standing`` (hatched); with a people sensor, who is ``unseen`` now
        (faded, dashed outline)."""
        from matplotlib.patches import Circle, Polygon

        ax, s = self.ax, self.scene
        ax.clear()
        if len(obstacles):
            corners = np.concatenate(obstacles)
            ax.set_xlim(corners[:, 0].min() - 0.3, corners[:, 0].max() + 0.3)
            ax.set_ylim(corners[:, 1].min() - 0.3, corners[:, 1].max() + 0.3)
            for vertices in obstacles:
                ax.add_patch(Polygon(vertices, closed=True, fc="0.55", ec="0.3", lw=0.8))
            ax.plot([], [], marker="s", color="0.55", ls="none", label="rack / wall")
        else:
            half = (max(s.circle_radius + 1.5, s.square_width / 2 + 1) if s.scenario == "square_crossing"
                    else s.circle_radius + 1.5)
            ax.set_xlim(-half, half)
            ax.set_ylim(-half, half)
        if route is not None:
            ax.plot(*np.asarray(route).T, color="tab:red", lw=1.0, ls="--", marker=".", ms=4, label="route")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        cmap = self.plt.get_cmap(HUMAN_CMAP)
        robot_path = np.array([r[Robot.POS] for r, _ in trajectory])
        ax.plot(robot_path[:, 0], robot_path[:, 1], color=ROBOT_COLOR, lw=1.5, label="robot trace")
        robot, humans = trajectory[-1]
        n = len(humans)
        if n:
            paths = np.array([h for _, h in trajectory])  # (steps, n, 2+)
            for i in range(n):
                c = cmap(i % 10)
                ax.plot(paths[:, i, 0], paths[:, i, 1], color=c, lw=0.8, alpha=0.6)
                hatch = "////" if standing is not None and i < len(standing) and standing[i] else None
                hidden = unseen is not None and i < len(unseen) and unseen[i]
                ax.add_patch(Circle(humans[i, :2], humans[i, 4], fc=c, ec="k", alpha=0.25 if hidden else 0.8,
                                    hatch=hatch, ls="--" if hidden else "-"))
                ax.plot(*human_goals[i], marker="x", color=c, ms=5)
        ax.add_patch(Circle(robot[Robot.POS], robot[Robot.RADIUS], fc=ROBOT_COLOR, ec="k"))
        h = robot[Robot.HEADING]
        ax.plot([robot[0], robot[0] + robot[Robot.RADIUS] * np.cos(h)], [robot[1], robot[1] + robot[Robot.RADIUS] * np.sin(h)],
                color="k", lw=1.5)
        ax.plot(*robot_goal, marker="*", color="red", ms=14, mec="k", ls="none", label="goal")
        if len(obstacles):  # the warehouse has more to tell apart
            ax.plot([], [], marker="o", color="0.5", ls="none",
                    label="picker (hatched: standing" + ("; faded: unseen)" if unseen is not None else ")"))
            ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=5, fontsize=6, frameon=False,
                      handlelength=1.5, columnspacing=1.0)
        ax.set_title(f"t = {time:.2f} s", pad=22 if len(obstacles) else 6)
        self.fig.canvas.draw()
        if self.human:
            self.plt.pause(0.001)
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        self.plt.close(self.fig)
