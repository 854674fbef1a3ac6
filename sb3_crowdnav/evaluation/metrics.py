"""Aggregate episode records into the paper's metrics (Tables 3-5).

Confidence intervals of the success / collision / timeout rates are **Wilson score intervals**
at 95 % (z = 1.959964): for k successes in n episodes, p̂ = k / n,

    centre = (p̂ + z²/(2n)) / (1 + z²/n)
    half   = z / (1 + z²/n) · sqrt(p̂(1 - p̂)/n + z²/(4n²))

Unlike the normal ("Wald") interval it stays inside [0, 1] and does not collapse to a point at
p̂ = 0 or 1 (0.99 over 500 episodes → [0.977, 0.996]).

Averages (see :class:`Summary`): the navigation time and path length over **successful**
episodes (as the field reports them), the returns, heading change, sharp turns and comfort-zone
time over **all** episodes, the minimum separation ("gap") over all episodes with at least one pedestrian present
during the episode (the records' ``steps_with_people`` > 0: a recorded scene's window can hold people none of whom
is present while the robot drives; a record without it, written before it, counts when it has ``num_humans`` > 0;
a collision contributes its value ≤ 0), and the discomfort frequency pooled over all steps
(Σ discomfort steps / Σ steps).

Two separations are pooled over **steps** rather than episodes, as the field's CrowdNav code
reports its "average min separate distance in danger": ``discomfort_separation``, the mean
minimum surface distance over all steps closer than the discomfort distance (0.2 m), and
``comfort_zone_separation``, the same over all steps inside a pedestrian's comfort ellipse
(Eq. 9). Both are ``nan`` when no episode has such a step. The paper's "gap" of Table 5 (0.14 m
for APG_RL, 0.64 / 0.50 m for the comfort variants) is consistent with these in-zone averages
(0.14 < 0.2 m; 0.64 and 0.50 fit inside the 0.7 m-wide comfort zone) and not with an
episode minimum, which is why the tables report both next to ``min_separation``.

The safety figures (the records' ``min_time_to_collision`` and the rest, from the people's true state) are averaged
over the episodes that carry them (every episode an env ran; a record built without them has a ``nan`` time-to-collision
and is left out of all of them): the minimum time-to-collision (each episode's capped at 10 s, so an episode
without anyone on a collision course counts as 10 s) and the share of episodes whose minimum is below 1 s; near misses
per episode; the peak acceleration and turn rate as the mean of the episodes' peaks and their maximum. The speed near
people is pooled over **steps** like the separations above (Σ speeds / Σ steps with a person within 1 m, ``nan`` when
no episode has one). The clearance to racks and walls (the warehouse's episodes only) is the mean of the episodes'
minima and the smallest of them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from sb3_crowdnav.sim.proximity import SHORT_TTC
from sb3_crowdnav.sim.validation import check_range

OUTCOMES = ("success", "collision", "timeout")


def z_value(confidence: float = 0.95) -> float:
    """Two-sided standard-normal quantile: 1.959964 for 95 %."""
    check_range("confidence", confidence, 0, 1, low_open=True, high_open=True)
    return NormalDist().inv_cdf(0.5 + confidence / 2)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval ``(low, high)`` of a binomial proportion ``successes / n``."""
    if n <= 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n, got successes={successes}, n={n}")
    z = z_value(confidence)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exact bounds: no rounding residue at k = 0 or n
    high = 1.0 if successes == n else min(1.0, centre + half)
    return (low, high)


def discounted_return(rewards: Sequence[float], gamma: float = 0.9, time_step: float = 0.25,
                      v_pref: float = 1.0) -> float:
    """Σ_t gamma^(t·Δt·v_pref)·r_t with t = 0, 1, ... (the "return" of Table 3; the env reports the same)."""
    r = np.asarray(rewards, dtype=np.float64)
    t = np.arange(len(r))
    return float(np.sum(gamma ** (t * time_step * v_pref) * r))


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else math.nan


@dataclass(frozen=True)
class Summary:
    """Metrics of a set of episodes; rates come with their Wilson 95 % interval ``(low, high)``."""

    episodes: int
    success_rate: float
    success_ci: tuple[float, float]
    collision_rate: float
    collision_ci: tuple[float, float]
    timeout_rate: float
    timeout_ci: tuple[float, float]
    navigation_time: float  # [s], successful episodes
    discounted_return: float  # Σ gamma^(t·Δt·v_pref) r_t, all episodes
    episode_return: float  # undiscounted, all episodes
    min_separation: float  # [m], "gap", episodes with pedestrians
    discomfort_frequency: float  # share of all steps
    comfort_zone_time: float  # [s] per episode
    heading_change: float  # [rad] per episode
    path_length: float  # [m], successful episodes
    discomfort_separation: float = math.nan  # [m], mean over all steps closer than 0.2 m
    comfort_zone_separation: float = math.nan  # [m], mean over all steps inside a comfort ellipse
    sharp_turns: float = math.nan  # per episode: steps turning by >= the angular-penalty threshold (Eq. 13)
    # the warehouse: collisions by what was hit, and the path of successful episodes over their planned route
    human_collision_rate: float = math.nan
    human_collision_ci: tuple[float, float] = (math.nan, math.nan)
    obstacle_collision_rate: float = math.nan
    obstacle_collision_ci: tuple[float, float] = (math.nan, math.nan)
    route_ratio: float = math.nan  # mean path length / route length, successful episodes
    # the safety figures (see the module docstring)
    min_time_to_collision: float = math.nan  # [s] mean of the episodes' minima, each capped at 10 s
    short_ttc_rate: float = math.nan  # share of the episodes whose minimum time-to-collision is below 1 s
    near_misses: float = math.nan  # per episode: steps closer than 0.2 m to a person without touching
    speed_near_people: float = math.nan  # [m/s] the robot's mean speed over all steps with a person within 1 m
    peak_acceleration: float = math.nan  # [m/s²] mean of the episodes' peaks
    peak_acceleration_max: float = math.nan  # [m/s²] the largest peak
    peak_turn_rate: float = math.nan  # [rad/s] mean of the episodes' peaks
    peak_turn_rate_max: float = math.nan  # [rad/s] the largest peak
    min_clearance: float = math.nan  # [m] to racks and walls: mean of the episodes' minima (the warehouse)
    min_clearance_worst: float = math.nan  # [m] the smallest of them

    @property
    def has_obstacles(self) -> bool:
        """The episodes ran in a world with static obstacles (the warehouse)."""
        return not math.isnan(self.obstacle_collision_rate)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _pooled(values: Sequence[float], weights: Sequence[float]) -> float:
    """Σ w·v / Σ w over the finite values with w > 0 (``nan`` when there are none)."""
    pairs = [(v, w) for v, w in zip(values, weights, strict=True) if w > 0 and math.isfinite(v)]
    total = sum(w for _, w in pairs)
    return sum(v * w for v, w in pairs) / total if total > 0 else math.nan


def _with_people(record: Any) -> bool:
    """Whether someone was present during the episode (``steps_with_people``; a record without it: ``num_humans``)."""
    known = getattr(record, "steps_with_people", -1)
    return known > 0 if known >= 0 else record.num_humans > 0


def summarize(records: Sequence[Any], confidence: float = 0.95) -> Summary:
    """Aggregate :class:`~sb3_crowdnav.evaluation.runner.EpisodeRecord` s into a :class:`Summary`."""
    records = list(records)
    n = len(records)
    if n == 0:
        raise ValueError("summarize needs at least one episode record")
    unknown = {r.outcome for r in records} - set(OUTCOMES)
    if unknown:
        raise ValueError(f"unknown outcome(s) {sorted(unknown)}; expected {OUTCOMES}")
    counts = {o: sum(r.outcome == o for r in records) for o in OUTCOMES}
    success = [r for r in records if r.outcome == "success"]
    seps = [r.min_separation for r in records if _with_people(r) and math.isfinite(r.min_separation)]
    total_steps = sum(r.steps for r in records)
    discomfort_steps = sum(r.discomfort_frequency * r.steps for r in records)
    return Summary(
        episodes=n,
        success_rate=counts["success"] / n,
        success_ci=wilson_interval(counts["success"], n, confidence),
        collision_rate=counts["collision"] / n,
        collision_ci=wilson_interval(counts["collision"], n, confidence),
        timeout_rate=counts["timeout"] / n,
        timeout_ci=wilson_interval(counts["timeout"], n, confidence),
        navigation_time=_mean([r.navigation_time for r in success]),
        discounted_return=_mean([r.discounted_return for r in records]),
        episode_return=_mean([r.episode_return for r in records]),
        min_separation=_mean(seps),
        discomfort_frequency=discomfort_steps / total_steps if total_steps else math.nan,
        comfort_zone_time=_mean([r.comfort_zone_time for r in records]),
        heading_change=_mean([r.heading_change for r in records]),
        path_length=_mean([r.path_length for r in success]),
        # weights proportional to each episode's number of such steps (the time step is common)
        discomfort_separation=_pooled([r.discomfort_separation for r in records],
                                      [r.discomfort_frequency * r.steps for r in records]),
        comfort_zone_separation=_pooled([r.comfort_zone_separation for r in records],
                                        [r.comfort_zone_time for r in records]),
        sharp_turns=_mean([r.sharp_turns for r in records]),
        **_obstacle_metrics(records, confidence),
        **_safety_metrics(records),
    )


def _obstacle_metrics(records: Sequence[Any], confidence: float) -> dict[str, Any]:
    """Human and obstacle collision rates and the route ratio, for episodes with a planned route (the warehouse)."""
    if not any(math.isfinite(getattr(r, "route_length", math.nan)) for r in records):
        return {}
    n = len(records)
    hits = {kind: sum(r.outcome == "collision" and r.collision_with == kind for r in records)
            for kind in ("human", "obstacle")}
    ratios = [r.path_length / r.route_length for r in records
              if r.outcome == "success" and math.isfinite(r.route_length) and r.route_length > 0]
    return {"human_collision_rate": hits["human"] / n, "human_collision_ci": wilson_interval(hits["human"], n, confidence),
            "obstacle_collision_rate": hits["obstacle"] / n,
            "obstacle_collision_ci": wilson_interval(hits["obstacle"], n, confidence), "route_ratio": _mean(ratios)}


def _safety_metrics(records: Sequence[Any]) -> dict[str, Any]:
    """The safety figures of the records that carry them (none: all ``nan``); the clearance of warehouse episodes."""
    safe = [r for r in records if math.isfinite(getattr(r, "min_time_to_collision", math.nan))]
    out: dict[str, Any] = {}
    if safe:
        ttc = [r.min_time_to_collision for r in safe]
        acc, turn = [r.peak_acceleration for r in safe], [r.peak_turn_rate for r in safe]
        out.update(
            min_time_to_collision=_mean(ttc), short_ttc_rate=sum(t < SHORT_TTC for t in ttc) / len(safe),
            near_misses=_mean([r.near_misses for r in safe]),
            speed_near_people=_pooled([r.speed_near_people for r in safe], [r.steps_near_people for r in safe]),
            peak_acceleration=_mean(acc), peak_acceleration_max=max(acc),
            peak_turn_rate=_mean(turn), peak_turn_rate_max=max(turn),
        )
    clearances = [r.min_clearance for r in records if math.isfinite(getattr(r, "min_clearance", math.nan))]
    if clearances:
        out.update(min_clearance=_mean(clearances), min_clearance_worst=min(clearances))
    return out


__all__ = ["OUTCOMES", "Summary", "discounted_return", "summarize", "wilson_interval", "z_value"]
