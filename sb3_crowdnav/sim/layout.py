"""Named slices of the observation vectors (SPEC §2.2); never use bare column numbers elsewhere."""

from __future__ import annotations

ROBOT_FIELDS = ("px", "py", "vx", "vy", "radius", "gx", "gy", "v_pref", "heading")
HUMAN_FIELDS = ("px", "py", "vx", "vy", "radius")
ROBOT_DIM = len(ROBOT_FIELDS)
HUMAN_DIM = len(HUMAN_FIELDS)


class Robot:
    """Columns of ``observation["robot"]`` (9,)."""

    POS = slice(0, 2)
    VEL = slice(2, 4)
    RADIUS = 4
    GOAL = slice(5, 7)
    V_PREF = 7
    HEADING = 8


class Human:
    """Columns of one pedestrian state (5,) in ``observation["humans"]`` viewed as (T, max_humans, 5)."""

    POS = slice(0, 2)
    VEL = slice(2, 4)
    RADIUS = 4
