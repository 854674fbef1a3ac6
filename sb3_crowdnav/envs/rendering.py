"""Matplotlib drawing of an episode: robot, pedestrians, goals, trails and the time."""

from __future__ import annotations

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

    def draw(self, trajectory, human_goals: np.ndarray, robot_goal: np.ndarray, time: float) -> np.ndarray:
        from matplotlib.patches import Circle

        ax, s = self.ax, self.scene
        ax.clear()
        half = max(s.circle_radius + 1.5, s.square_width / 2 + 1) if s.scenario == "square_crossing" else s.circle_radius + 1.5
        ax.set_xlim(-half, half)
        ax.set_ylim(-half, half)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        cmap = self.plt.get_cmap(HUMAN_CMAP)
        robot_path = np.array([r[Robot.POS] for r, _ in trajectory])
        ax.plot(robot_path[:, 0], robot_path[:, 1], color=ROBOT_COLOR, lw=1.5)
        robot, humans = trajectory[-1]
        n = len(humans)
        if n:
            paths = np.array([h for _, h in trajectory])  # (steps, n, 2+)
            for i in range(n):
                c = cmap(i % 10)
                ax.plot(paths[:, i, 0], paths[:, i, 1], color=c, lw=0.8, alpha=0.6)
                ax.add_patch(Circle(humans[i, :2], humans[i, 4], fc=c, ec="k", alpha=0.8))
                ax.plot(*human_goals[i], marker="x", color=c, ms=5)
        ax.add_patch(Circle(robot[Robot.POS], robot[Robot.RADIUS], fc=ROBOT_COLOR, ec="k"))
        h = robot[Robot.HEADING]
        ax.plot([robot[0], robot[0] + robot[Robot.RADIUS] * np.cos(h)], [robot[1], robot[1] + robot[Robot.RADIUS] * np.sin(h)],
                color="k", lw=1.5)
        ax.plot(*robot_goal, marker="*", color="red", ms=14, mec="k")
        ax.set_title(f"t = {time:.2f} s")
        self.fig.canvas.draw()
        if self.human:
            self.plt.pause(0.001)
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        self.plt.close(self.fig)


class WarehouseRenderer(CrowdRenderer):
    """The warehouse: racks and walls, the robot's route, pickers (standing ones hatched), the robot's trace."""

    def draw_warehouse(self, trajectory, sim, time: float) -> np.ndarray:
        from matplotlib.patches import Circle, Polygon

        ax, layout = self.ax, sim.layout
        ax.clear()
        margin = 0.8
        ax.set_xlim(-layout.width / 2 - margin, layout.width / 2 + margin)
        ax.set_ylim(-layout.height / 2 - margin, layout.height / 2 + margin)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        for vertices in layout.polygons:
            ax.add_patch(Polygon(vertices, closed=True, fc="0.55", ec="0.3", lw=0.8))
        ax.plot(*sim.route.T, color="tab:red", lw=1.0, ls="--", marker=".", ms=4, label="route")
        robot_path = np.array([r[Robot.POS] for r, _ in trajectory])
        ax.plot(robot_path[:, 0], robot_path[:, 1], color=ROBOT_COLOR, lw=1.5, label="robot trace")
        robot, humans = trajectory[-1]
        standing = sim.standing
        cmap = self.plt.get_cmap(HUMAN_CMAP)
        for i in range(len(humans)):
            c = cmap(i % 10)
            ax.add_patch(Circle(humans[i, :2], humans[i, 4], fc=c, ec="k", alpha=0.85,
                                hatch="////" if i < len(standing) and standing[i] else None))
        ax.add_patch(Circle(robot[Robot.POS], robot[Robot.RADIUS], fc=ROBOT_COLOR, ec="k"))
        h = robot[Robot.HEADING]
        ax.plot([robot[0], robot[0] + robot[Robot.RADIUS] * np.cos(h)],
                [robot[1], robot[1] + robot[Robot.RADIUS] * np.sin(h)], color="k", lw=1.5)
        ax.plot(*robot[Robot.GOAL], marker="*", color="red", ms=14, mec="k", ls="none", label="goal")
        ax.plot([], [], marker="o", color="0.5", ls="none", label="picker (hatched: standing)")
        ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=4, fontsize=7, frameon=False)
        ax.set_title(f"t = {time:.2f} s", pad=22)
        self.fig.canvas.draw()
        if self.human:
            self.plt.pause(0.001)
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()
