"""Per-rollout crowd statistics for TensorBoard: collision and timeout rates, navigation time, minimum separation."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.utils import safe_mean


class RolloutStats:
    """The last ``window`` finished episodes' ``info["episode_stats"]``, logged as ``rollout/*``.

    ``rollout/success_rate`` comes from SB3 itself (``info["is_success"]``).
    """

    def __init__(self, window: int) -> None:
        self.outcomes: deque[str] = deque(maxlen=window)
        self.navigation_times: deque[float] = deque(maxlen=window)  # successful episodes only
        self.min_separations: deque[float] = deque(maxlen=window)

    def update(self, infos: Iterable[dict[str, Any]]) -> None:
        """Read the episode statistics of the envs whose episode ended in this step."""
        for info in infos:
            stats = info.get("episode_stats")
            if stats is None:
                continue
            self.outcomes.append(stats["outcome"])
            self.min_separations.append(stats["min_separation"])
            if stats["outcome"] == "success":
                self.navigation_times.append(stats["navigation_time"])

    def record(self, logger: Logger) -> None:
        """Record the window's rates and means (nothing before the first finished episode)."""
        if not self.outcomes:
            return
        for outcome in ("collision", "timeout"):
            logger.record(f"rollout/{outcome}_rate", self.outcomes.count(outcome) / len(self.outcomes))
        if self.navigation_times:
            logger.record("rollout/navigation_time", safe_mean(list(self.navigation_times)))
        finite = [d for d in self.min_separations if np.isfinite(d)]
        if finite:
            logger.record("rollout/min_separation", safe_mean(finite))
