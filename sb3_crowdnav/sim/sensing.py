"""What the robot sees of the people: a sensor between the crowd's true state and the observation (numpy only).

Without any of its settings (``CrowdNav-v0``'s defaults) the observation is the crowd's true state and no sensor is
built. With one of them, :class:`PeopleSensor` builds the observed history the env hands to the policy, while the
simulator keeps the true one for the dynamics, the rewards and the collisions (a collision counts with everyone,
seen or not). The rules, each a scene setting:

* **range** (``people_sensor_range`` [m], None: unlimited): a person is seen when their disc comes within the range
  of the robot's centre (centre distance - radius <= range);
* **occlusion** (the warehouse's ``occlusion``): a person is seen only when a line of sight from the robot's centre
  reaches their disc past the racks: one of three lines, to the centre of the disc and to its two sides across the
  line of sight, enters no rack (grazing a rack's side or corner does not block). Walls never block (everyone is
  inside the hall) and people do not hide one another: the racks are what a warehouse's sensors cannot see through,
  and a tracker keeps a person who is briefly behind another;
* **noise** (``people_sensor_noise`` [m]): each seen position gets independent Normal(0, σ²) noise per axis; the
  velocities and radii are reported exactly (a tracker's estimates). The noise comes from a child of the episode's
  generator (``Generator.spawn`` at the reset, which leaves the parent's draws as they were): the people, the robot
  and every outcome are those of the noise-free episode, only what the robot sees differs;
* **latency** (``people_sensor_latency`` [steps]): the observation at step t shows the people as sensed at step
  t - L, from where the robot was then; before L steps have passed, as sensed at the reset. The robot's own state
  is never late.

**Who fills the slots** (``observed``): with ``"all"`` (the default) person i is in slot i. With ``"nearest"`` the
observation's ``max_humans`` slots hold the people nearest to the robot's centre among those seen (by their observed
position, ties in the crowd's order), as a tracker reports its N nearest tracks: a person still among them keeps
their slot, one who enters takes the lowest free slot (nearest first) and starts a new history there, one who
drops out leaves their slot padded. The simulator then moves more people than the observation holds
(``num_humans`` > ``max_humans``). Replay's ``tracked="nearest"`` fills its slots by the same rule
(:func:`assign_slots`), measuring from the robot at the start of the step; the sensor measures from where it senses.

**History is built from what was seen.** Each slot keeps the last T observed states of its person. A person not seen
in the frame delivered now has their slot padded over the whole window (zeros, mask 0), and a person seen again
starts a new history (their observed state repeated over the window, as at a reset): a history never bridges a gap,
so a constant-velocity prediction is never made from a stale position. The mask says who is seen now.
"""

from __future__ import annotations

from collections import deque
from typing import Any, Protocol

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human


class Occluder(Protocol):
    """What hides people from the robot (the warehouse's racks: :class:`~sb3_crowdnav.sim.warehouse.sight.RackSight`)."""

    def frame(self, x: float, y: float, row: np.ndarray, present: np.ndarray,
              sensor_range: float | None) -> tuple[np.ndarray, np.ndarray]:
        """One frame of this module's rules without noise: the states (M, 5) of the people of ``row`` (M, 5) seen
        from (x, y) (zeros for the others) and who is seen (M,), of those ``present`` within ``sensor_range``."""

    def deliver(self, x: float, y: float, row: np.ndarray, present: np.ndarray, sensor_range: float | None,
                history: np.ndarray, mask: np.ndarray) -> bool:
        """:meth:`frame` delivered straight into an observed ``history`` (T, M, 5) and its ``mask`` (M,) by
        :func:`deliver` (a sensor without latency, noise or ``"nearest"``); False when it cannot (nothing done)."""


@njit(**JIT)
def deliver(history, mask, states, seen):  # pragma: no cover  (compiled)
    """Shift the observed history (T, M, 5) by one step and put the frame (``states`` (M, 5), ``seen`` (M,)) in it by
    the module's rules; ``mask`` (M,) becomes ``seen``."""
    t_len, m = history.shape[0], history.shape[1]
    for t in range(t_len - 1):
        history[t] = history[t + 1]
    for i in range(m):
        if not seen[i]:
            history[:, i] = 0.0  # not seen now: padded over the whole window
        elif not mask[i]:
            for t in range(t_len):  # seen again (or for the first time): a new history
                history[t, i] = states[i]
        else:
            history[t_len - 1, i] = states[i]
        mask[i] = seen[i]


def sensing_on(scene: Any, occlusion: bool = False) -> bool:
    """Whether ``scene`` (a :class:`~sb3_crowdnav.sim.config.SceneConfig`) with ``occlusion`` needs a sensor: some
    setting hides or alters what the robot sees of the people, or chooses whom it observes."""
    return bool(occlusion or scene.people_sensor_range is not None or scene.people_sensor_noise > 0
                or scene.people_sensor_latency > 0 or scene.observed == "nearest")


def assign_slots(slots: list[int], chosen: list[int]) -> tuple[list[int], list[int]]:
    """The slots (person or -1 each) after ``chosen`` (people, nearest first) are to be observed: a chosen person in a
    slot keeps it, the other slots are emptied, and each chosen newcomer takes the lowest free slot, in ``chosen``'s
    order. Returns the new slots and the slots newcomers took. ``len(chosen)`` must not exceed the slots."""
    keep = set(chosen)
    new = [p if p in keep else -1 for p in slots]
    held = set(new)
    entered = []
    for person in chosen:
        if person not in held:
            s = new.index(-1)
            new[s] = person
            entered.append(s)
    return new, entered


class PeopleSensor:
    """The observed pedestrian history of one episode, built from the true state by the rules of this module.

    :param scene: ``history_length``, ``max_humans`` and the ``people_sensor_*`` settings
    :param occluder: what hides people (set per episode with :attr:`occluder`); None: nothing does
    """

    def __init__(self, scene: Any, occluder: Occluder | None = None) -> None:
        self.range = scene.people_sensor_range
        self.noise = float(scene.people_sensor_noise)
        self.latency = int(scene.people_sensor_latency)
        self.occluder = occluder
        self.nearest = scene.observed == "nearest"
        self._direct = self.latency == 0 and self.noise == 0 and not self.nearest  # a frame is delivered as sensed
        self.history = np.zeros((scene.history_length, scene.max_humans, HUMAN_DIM))
        self.mask = np.zeros(scene.max_humans, dtype=bool)
        # the person in each slot of the history delivered last, -1: none (the identity without ``nearest``)
        self.people = np.arange(scene.max_humans)
        self._slots = [-1] * scene.max_humans  # the slots as sensed last (ahead of ``people`` by the latency)
        # (states, seen, slots entered by newcomers, the person in each slot) of the frames not delivered yet
        self._frames: deque[tuple[np.ndarray, np.ndarray, list[int], np.ndarray]] = deque(maxlen=self.latency + 1)
        self._rng: np.random.Generator | None = None

    def reset(self, rng: np.random.Generator, x: float, y: float, row: np.ndarray, present: np.ndarray) -> None:
        """Start an episode: sense the people (``row`` (N, 5), the true newest states; ``present`` (N,) bool; N is
        ``max_humans``, or more with ``observed="nearest"``) from the robot's centre (x, y); the observed history is
        that frame repeated."""
        self._rng = rng.spawn(1)[0] if self.noise > 0 else None
        self._frames.clear()
        self._slots = [-1] * len(self.mask)
        states, seen, _, people = frame = self._sense(x, y, row, present)
        self._frames.append(frame)
        self.history[:] = states[None]
        self.mask = seen.copy()
        self.people = people

    def step(self, x: float, y: float, row: np.ndarray, present: np.ndarray) -> None:
        """Sense after a step (as :meth:`reset`) and deliver the frame of ``latency`` steps ago into the history (the
        occluder delivers it itself when it can and nothing else alters the frame)."""
        if self._direct and self.occluder is not None and \
                self.occluder.deliver(x, y, row, present, self.range, self.history, self.mask):
            return
        self._frames.append(self._sense(x, y, row, present))
        states, seen, entered, self.people = self._frames[0]
        if entered:  # a newcomer in a slot starts a new history, as one seen again does
            self.mask[entered] = False
        deliver(self.history, self.mask, states, seen)

    def seen_people(self, n: int) -> np.ndarray:
        """(n,) bool: which of the crowd's first ``n`` people are in the observation delivered last."""
        out = np.zeros(n, dtype=bool)
        out[self.people[self.mask]] = True
        return out

    def _sense(self, x: float, y: float, row: np.ndarray, present: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, list[int], np.ndarray]:
        """One frame: the observed states (max_humans, 5; zero where not seen), who is seen (max_humans,), the slots
        newcomers took and the person in each slot."""
        if self.occluder is not None:
            states, seen = self.occluder.frame(x, y, row, present, self.range)
        else:
            states, seen = open_frame(x, y, row, present, self.range)
        if self._rng is not None and seen.any():
            states[seen, Human.POS] += self._rng.normal(0.0, self.noise, (int(seen.sum()), 2))
        if not self.nearest:
            return states, seen, [], self.people
        here = np.flatnonzero(seen)
        order = np.argsort(np.hypot(states[here, 0] - x, states[here, 1] - y), kind="stable")
        self._slots, entered = assign_slots(self._slots, here[order[: len(self.mask)]].tolist())
        people = np.array(self._slots)
        taken = people >= 0
        return np.where(taken[:, None], states[np.where(taken, people, 0)], 0.0), taken, entered, people


def open_frame(x: float, y: float, row: np.ndarray, present: np.ndarray,
               sensor_range: float | None) -> tuple[np.ndarray, np.ndarray]:
    """A frame with nothing to hide anyone (:meth:`Occluder.frame`'s form): the range alone."""
    seen = np.array(present, dtype=bool)
    if sensor_range is not None and seen.any():
        seen &= np.hypot(row[:, 0] - x, row[:, 1] - y) - row[:, Human.RADIUS] <= sensor_range
    return np.where(seen[:, None], row, 0.0), seen


__all__ = ["Occluder", "PeopleSensor", "assign_slots", "deliver", "open_frame", "sensing_on"]
