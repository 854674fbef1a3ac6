"""examples/closest_approach.py: which side of the closest pedestrian the robot passes."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from sb3_crowdnav import CrowdNavEnv
from sb3_crowdnav.sim.observation import Human, Robot

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "closest_approach.py"
NS = runpy.run_path(str(SCRIPT))


def _obs(humans: list[tuple[tuple[float, float], tuple[float, float]]], mask: list[float], t_len: int = 5) -> dict:
    env = CrowdNavEnv(num_humans=len(mask), max_humans=len(mask))
    obs, _ = env.reset(seed=0)
    obs["robot"][Robot.POS] = 0.0, 0.0
    hist = obs["humans"].reshape(t_len, len(mask), -1)
    for i, (pos, vel) in enumerate(humans):
        hist[:, i, Human.POS] = pos
        hist[:, i, Human.VEL] = vel
        hist[:, i, Human.RADIUS] = 0.3
    obs["humans_mask"][:] = mask
    return obs


@pytest.mark.parametrize(("vel", "front"), [((1.0, 0.0), False), ((-1.0, 0.0), True), ((0.0, 1.0), True)])
def test_side_follows_the_walking_direction(vel, front):
    # a pedestrian 1.6 m to the right: walking away from the robot (+x) leaves it behind, walking towards it
    # (-x) puts it in front, walking sideways puts it on the boundary x0 = 0, which Eq. 11 counts as front
    dist, is_front = NS["closest_approach"](_obs([((1.6, 0.0), vel), ((0.5, 0.0), (1.0, 0.0))], [1.0, 0.0]))
    assert dist == pytest.approx(1.6 - 0.3 - 0.3, abs=1e-6)  # the padded slot at 0.5 m is ignored
    assert is_front == front


def test_standing_pedestrian_keeps_its_last_direction():
    obs = _obs([((1.6, 0.0), (0.0, 0.0))], [1.0])
    obs["humans"].reshape(5, 1, -1)[0, 0, Human.VEL] = (1.0, 0.0)  # walked away from the robot, then stopped
    assert NS["closest_approach"](obs)[1] is False


def test_cli_counts_every_episode(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), "--policy", "orca", "--episodes", "3"])
    runpy.run_path(str(SCRIPT), run_name="__main__")
    row = capsys.readouterr().out.strip().splitlines()[-1]
    cells = [c.strip() for c in row.strip("|").split("|")]
    front, behind = int(cells[2].split()[0]), int(cells[3])
    assert cells[0] == "ORCA" and cells[1] == "3" and front + behind == 3
    assert np.isfinite(float(cells[4]))
