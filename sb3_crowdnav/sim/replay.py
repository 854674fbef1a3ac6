"""``crowd="replay"``: people who walk as recorded (ETH/UCY or a ``t,id,x,y`` CSV), seeing no one.

An episode is a window of the recording: ``time_limit`` seconds from a start time (``start_time``, or drawn per
episode), sampled every Δt. At each step time t:

* **who is present**: the people whose first sample is at or before t + ``lead_in`` and whose last is at or after
  t (within ``time_window``); people appear and vanish as recorded (with ``lead_in`` > 0, that long before their
  first sample, walking back along their first segment). A person who appears takes the lowest free slot of the
  observation (free from the first step its previous person is absent; the first of equals in file order); a
  vanished person's slot is padded (zeros, mask 0). The recording's most people present at once must fit
  ``max_humans`` (checked at construction), unless ``tracked="nearest"``: then, in a window with more people
  present at once than ``max_humans``, the slots hold the ``max_humans`` present people nearest to the robot at the
  start of each step (a tracker's N nearest tracks), each keeping its slot while it stays among them. With
  ``appear="clear"`` a person who would appear touching the robot during the step (:func:`touching`) is held back,
  absent, and appears at the first step in which they would not, where the recording has them then.
* **positions**: the recording's samples interpolated linearly to t.
* **velocities**: backward differences over one step, ``(p(t) - p(t - Δt)) / Δt``, so that ``p(t) = p(t - Δt) +
  v(t) Δt`` as the ORCA crowd integrates. Before its first sample a person's position is extended back along its first
  segment: a person who walks into view walks from its first step on. (A recording of ``CrowdNav-v0``'s people at
  rest at reset therefore begins one Δt before the episode, at their starts: see the docs' replay page.)

The robot's start and goal are ``crowd_kwargs``' ``robot_start`` and ``robot_goal``, or placed per episode across
the window's busy part by this seeded rule: the people's positions at the window's steps are counted in cells of
:data:`CELL` m; the crossing's centre is the mean of the positions in the fullest cell (the first of equals); a
direction is drawn uniformly; start and goal lie ``crossing_length / 2`` (4 m) before and after the centre. A start
closer than the two radii + 0.2 m to a person present at the first step is redrawn (direction and, when drawn, start
time), up to :data:`MAX_TRIES` times. The robot faces its goal. Draws: the start time, then the direction.
"""

from __future__ import annotations

import math

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd_settings import ReplayCrowdSettings
from sb3_crowdnav.sim.geometry import point_segment_distance
from sb3_crowdnav.sim.population import People
from sb3_crowdnav.sim.scenarios import MIN_GAP, Scenario
from sb3_crowdnav.sim.sensing import assign_slots

CELL = 1.0  # [m] side of the cells in which the placement rule counts the people
MAX_TRIES = 100


def _positions_at(times: np.ndarray, positions: np.ndarray, at: np.ndarray) -> np.ndarray:
    """One person's positions (len(at), 2) at times ``at`` [s]: linear between its samples, and before its first one
    extended along its first segment (``at`` never lies after its last sample here)."""
    out = np.stack([np.interp(at, times, positions[:, 0]), np.interp(at, times, positions[:, 1])], axis=-1)
    before = at < times[0]
    if before.any():
        slope = (positions[1] - positions[0]) / (times[1] - times[0])
        out[before] = positions[0] + (at[before, None] - times[0]) * slope
    return out


def touching(positions: np.ndarray, start: tuple[float, float], end: tuple[float, float], reach: float) -> np.ndarray:
    """(n,) bool: the people standing at ``positions`` (n, 2) whose centre comes within ``reach`` (the robot's radius
    plus a person's) of the robot's centre as it moves from ``start`` to ``end`` (the reward's collision test for a
    person who does not move in the step, as one who appears does not)."""
    if not len(positions):
        return np.zeros(0, dtype=bool)
    return point_segment_distance(positions, np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)) < reach


class ReplayCrowdModel:
    """People replayed from a recording (module docstring); a crowd that brings its own episodes.

    After :meth:`draw_scenario` (at reset) and each :meth:`step`, ``present`` (n,) says who is present and
    ``arrivals`` (n,) which slots a person took at that step; ``velocities`` (n, 2) are the people's velocities at the
    episode's first step. The people ignore the robot and the preferred velocities.
    """

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.settings: ReplayCrowdSettings = scene.crowd_kwargs
        rec = self.settings.recording
        self.first, self.last = rec.first - self.settings.lead_in, rec.last  # present from first - lead_in
        self.window = self.settings.window
        self.duration = scene.max_steps * scene.time_step  # [s] one episode
        self.positions = np.zeros((0, 0, 2))  # (steps + 1, n, 2) of the episode
        self.all_velocities = np.zeros((0, 0, 2))
        self.all_present = np.zeros((0, 0), dtype=bool)
        self.all_arrivals = np.zeros((0, 0), dtype=bool)
        self.present = np.zeros(0, dtype=bool)
        self.arrivals = np.zeros(0, dtype=bool)
        self.velocities = np.zeros((0, 2))
        self.k = 0
        self.tracks: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # tracked="nearest", too many people
        self.slot_person = np.zeros(0, dtype=np.int64)  # (max_humans,) the person in each slot then, -1: none
        self.clear = self.settings.appear == "clear"  # hold back a person who would appear touching the robot
        self.reach = scene.robot_radius + scene.human_radius
        self.waiting = np.zeros(0, dtype=bool)  # appear="clear": per slot, its person is due and held back
        self.appeared = np.zeros(0, dtype=bool)  # appear="clear", tracked="nearest": per person, has appeared
        s = self.settings
        if s.start_time is not None and s.robot_start is None and not self._overlapping(s.start_time).size:
            raise ValueError(f"crowd_kwargs: no one is present from start_time {s.start_time!r} s for the episode's "
                             f"{self.duration!r} s, so the robot cannot be placed across the busy part: give "
                             "robot_start and robot_goal, or another start_time")

    # ------------------------------------------------------------------ an episode's window
    def _overlapping(self, t0: float) -> np.ndarray:
        lo, hi = max(t0, self.window[0]), min(t0 + self.duration, self.window[1])
        return np.flatnonzero((self.last >= lo) & (self.first <= hi))

    def _window(self, t0: float) -> None:
        """Every step's positions, velocities, presence and arrivals of the episode starting at ``t0`` [s]."""
        dt, steps = self.scene.time_step, self.scene.max_steps
        index = np.arange(steps + 1)
        times = t0 + index * dt
        previous = t0 + (index - 1) * dt  # (not times - dt: p(t - Δt) is then bit for bit p of the step before)
        rec, (lo, hi) = self.settings.recording, self.window
        people = []  # (first step, last step, person)
        for i in self._overlapping(t0).tolist():
            a = int(np.searchsorted(times, max(self.first[i], lo), side="left"))
            b = int(np.searchsorted(times, min(self.last[i], hi), side="right")) - 1
            if a <= b:
                people.append((a, b, i))
        people.sort()
        if self.settings.tracked == "nearest":
            tracks = self._tracks(people, times, previous)
            if int(tracks[2].sum(axis=1).max(initial=0)) > self.scene.max_humans:
                self.tracks = tracks
                self.positions, self.all_velocities, self.all_present = tracks  # (for the placement rule)
                return
        self.tracks = None
        slot_end: list[int] = []  # the last step of each slot's latest person
        slots = []
        for a, b, _ in people:
            free = next((s for s, end in enumerate(slot_end) if end < a), len(slot_end))
            if free == len(slot_end):
                slot_end.append(b)
            else:
                slot_end[free] = b
            slots.append(free)
        n = len(slot_end)
        pos = np.zeros((steps + 1, n, 2))
        vel = np.zeros((steps + 1, n, 2))
        present = np.zeros((steps + 1, n), dtype=bool)
        arrivals = np.zeros((steps + 1, n), dtype=bool)
        for (a, b, i), s in zip(people, slots, strict=True):
            both = _positions_at(rec.times[i], rec.positions[i], np.concatenate([times[a:b + 1], previous[a:b + 1]]))
            here, before = both[: b + 1 - a], both[b + 1 - a:]
            pos[a:b + 1, s] = here
            vel[a:b + 1, s] = (here - before) / dt
            present[a:b + 1, s] = True
            arrivals[a, s] = True
        self.positions, self.all_velocities, self.all_present, self.all_arrivals = pos, vel, present, arrivals

    def _tracks(self, people: list[tuple[int, int, int]], times: np.ndarray, previous: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every person's positions, velocities (steps + 1, P, 2) and presence (steps + 1, P) in the window, one
        column per person (``tracked="nearest"``: the slots are chosen per step)."""
        rec, dt, steps = self.settings.recording, self.scene.time_step, self.scene.max_steps
        pos = np.zeros((steps + 1, len(people), 2))
        vel = np.zeros_like(pos)
        present = np.zeros((steps + 1, len(people)), dtype=bool)
        for j, (a, b, i) in enumerate(people):
            both = _positions_at(rec.times[i], rec.positions[i], np.concatenate([times[a:b + 1], previous[a:b + 1]]))
            here, before = both[: b + 1 - a], both[b + 1 - a:]
            pos[a:b + 1, j] = here
            vel[a:b + 1, j] = (here - before) / dt
            present[a:b + 1, j] = True
        return pos, vel, present

    def _track_nearest(self, k: int, start: tuple[float, float], end: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """``tracked="nearest"``: the slots at step ``k`` hold the ``max_humans`` present people nearest to the robot's
        ``start`` (ties in file order); a person still among them keeps its slot, one who enters takes the lowest free
        slot (nearest first) and is an arrival. With ``appear="clear"`` only the people who have appeared count
        (:meth:`_held_back`). Sets ``present``/``arrivals``; returns the slots' positions and velocities."""
        pos, vel, present = (a[k] for a in self.tracks)
        if self.clear:
            due = present & ~self.appeared
            due[due] = ~touching(pos[due], start, end, self.reach)
            self.appeared |= due
            present = present & self.appeared
        n = len(self.slot_person)
        here = np.flatnonzero(present)
        order = np.argsort(np.linalg.norm(pos[here] - np.asarray(start), axis=-1), kind="stable")
        slots, entered = assign_slots(self.slot_person.tolist(), here[order[:n]].tolist())
        arrivals = np.zeros(n, dtype=bool)
        arrivals[entered] = True
        self.slot_person = np.array(slots)
        taken = self.slot_person >= 0
        who = np.where(taken, self.slot_person, 0)
        self.present, self.arrivals = taken, arrivals
        return np.where(taken[:, None], pos[who], 0.0), np.where(taken[:, None], vel[who], 0.0)

    def _held_back(self, k: int, start: tuple[float, float], end: tuple[float, float]) -> None:
        """``present``/``arrivals`` at step ``k`` of the slots (not tracked by nearness): as recorded, or with
        ``appear="clear"`` without the people held back, a slot's due person arriving at the first step in which they
        would not touch the robot moving from ``start`` to ``end``."""
        present, arrivals = self.all_present[k], self.all_arrivals[k]
        if self.clear:  # (the due include this step's arrivals; one who vanishes while held back never appears)
            due = (self.waiting | arrivals) & present
            held = due.copy()
            held[held] = touching(self.positions[k][held], start, end, self.reach)
            arrivals, present, self.waiting = due & ~held, present & ~held, held
        self.present, self.arrivals = present, arrivals

    def _crossing(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
        """The placed start and goal (2,) of the current window, or None when its start is taken or no one is there."""
        samples = self.positions[self.all_present]
        if not len(samples):
            return None
        cells = np.floor(samples / CELL).astype(np.int64)
        cells -= cells.min(axis=0)
        key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]  # cells in (x, y) order
        centre = samples[key == int(np.argmax(np.bincount(key)))].mean(axis=0)
        angle = rng.uniform(0.0, 2 * math.pi)
        half = self.settings.crossing_length / 2 * np.array([math.cos(angle), math.sin(angle)])
        start, goal = centre - half, centre + half
        clearance = self.scene.robot_radius + self.scene.human_radius + MIN_GAP
        near = np.linalg.norm(self.positions[0][self.all_present[0]] - start, axis=-1) < clearance
        return None if near.any() else (start, goal)

    def _draw_start_time(self, rng: np.random.Generator) -> float:
        if self.settings.start_time is not None:
            return self.settings.start_time
        lo, hi = self.window
        return float(rng.uniform(lo, max(lo, hi - self.duration)))

    def draw_scenario(self, rng: np.random.Generator) -> Scenario:
        """The episode's window and the robot's start and goal (the people's starts: their positions at the first
        step, zero in an empty slot; their goals: where each slot's first person is last seen in the window)."""
        s = self.settings
        for _ in range(MAX_TRIES):
            self._window(self._draw_start_time(rng))
            if s.robot_start is not None:
                start, goal = np.array(s.robot_start), np.array(s.robot_goal)
                break
            crossing = self._crossing(rng)
            if crossing is not None:
                start, goal = crossing
                break
        else:
            raise RuntimeError(f"could not place the robot across {s.path} in {MAX_TRIES} tries (no one there, or "
                               "always someone on its start): give robot_start and robot_goal")
        self.k = 0
        (sx, sy), (gx, gy) = start.tolist(), goal.tolist()
        if self.tracks is not None:  # tracked="nearest" with more people than slots
            self.slot_person = np.full(self.scene.max_humans, -1)
            self.appeared = np.zeros(self.tracks[2].shape[1], dtype=bool)
            starts, self.velocities = self._track_nearest(0, (sx, sy), (sx, sy))
            last_seen = self.tracks[2].shape[0] - 1 - np.argmax(self.tracks[2][::-1], axis=0)  # of each person
            goals = np.where(self.present[:, None], self.tracks[0][last_seen[self.slot_person], self.slot_person], 0.0)
            return Scenario(start, goal, math.atan2(gy - sy, gx - sx), starts, goals)
        n = self.positions.shape[1]
        self.waiting = np.zeros(n, dtype=bool)
        self._held_back(0, (sx, sy), (sx, sy))
        self.velocities = self.all_velocities[0]
        last_seen = self.all_present.shape[0] - 1 - np.argmax(self.all_present[::-1], axis=0)  # of each slot
        goals = self.positions[last_seen, np.arange(n)] if n else np.zeros((0, 2))
        return Scenario(start, goal, math.atan2(gy - sy, gx - sx), self.positions[0].copy(), goals)

    # ------------------------------------------------------------------ the crowd-model seam
    def reset(self, rng: np.random.Generator, people: People, robot: object, walls: object = None) -> None:
        """Nothing to draw: :meth:`draw_scenario` set the episode."""

    def step(self, preferred: list[tuple[float, float]], robot: object) -> tuple[np.ndarray, np.ndarray]:
        """The next step's recorded positions and velocities (n, 2); zeros in empty slots."""
        self.k = k = min(self.k + 1, len(self.positions) - 1)
        end = robot.position if robot.end_position is None else robot.end_position
        if self.tracks is not None:
            return self._track_nearest(k, robot.position, end)
        self._held_back(k, robot.position, end)
        return self.positions[k], self.all_velocities[k]


__all__ = ["CELL", "MAX_TRIES", "ReplayCrowdModel", "touching"]
