"""The training recipes of ``sb3-crowdnav train --variant NAME``: each variant's policy, reward, world and the
schedule settings it changes from the paper's (:data:`PAPER_SCHEDULE`); :class:`~sb3_crowdnav.training.ScheduleConfig`
fills what a user leaves unset from them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sb3_crowdnav.sim.warehouse.config import PAPER_WAREHOUSE


@dataclass(frozen=True)
class Variant:
    """A row of the paper's tables: the value network (a policy alias of APGValue), its env and reward.

    :param env_kwargs: the variant's env settings (a run's own ``env_kwargs`` override them)
    :param schedule: the variant's defaults of :class:`ScheduleConfig` fields left None
    """

    policy: str
    reward: str = "crowdnav"
    env_id: str = "CrowdNav-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    schedule: dict[str, Any] = field(default_factory=dict)


# §3: ε from 0.5 to 0.1 over 5,000 episodes; one gradient step every 4 env steps unless a variant's test row says 8
PAPER_SCHEDULE = {"rl_episodes": 10_000, "exploration_episodes": 5_000, "train_freq": 4, "num_humans": 6,
                  "imitation_epochs": 10, "checkpoint_episodes": 500, "planning_depth": 1}


VARIANTS = {
    "apg_rl": Variant("ApgPolicy", schedule={"train_freq": 8}),  # 8: the same test row in half the time (two seeds)
    "apg_crl": Variant("ApgPolicy", "comfort"),
    "apg_carl": Variant("ApgPolicy", "comfort_angular"),
    "cadrl": Variant("CadrlPolicy"),
    "sf_rl": Variant("SfPolicy"),
    "lm_rl": Variant("LmPolicy"),
    "lstm_rl": Variant("LstmRlPolicy"),
    "sarl": Variant("SarlPolicy"),
    # the paper's method among racks with route-progress shaping, for the warehouse robot among 4 to 10 ORCA and
    # social-force pickers (docs/training.md); the schedule cut to fit 2 hours on 2 cores of an AVX2 machine
    "apg_warehouse": Variant("ApgPolicy", env_id="CrowdNavWorlds-v0",
                             env_kwargs={"worlds": "warehouse", "progress_reward": 0.1},
                             schedule={"rl_episodes": 7_000, "exploration_episodes": 3_500, "num_humans": (4, 10),
                                       "pedestrian_model": "cautious", "stopping_check": True, "imitation_epochs": 5,
                                       "train_freq": 8, "planning_depth": 2}),
    # the same in the world the shipped apg_warehouse was trained in: the paper's robot among blind ORCA pickers,
    # seen through racks at any range (sim.warehouse.config.PAPER_WAREHOUSE)
    "apg_warehouse_paper": Variant("ApgPolicy", env_id="CrowdNavWarehouse-v0",
                                   env_kwargs={"progress_reward": 0.1, **PAPER_WAREHOUSE},
                                   schedule={"rl_episodes": 6_000, "exploration_episodes": 3_000}),
    # the paper's method for people it never met: one of several crowds per episode, 0 to 10 people, a robot that can
    # stop (docs/decisions.md, "Robust training", "A stop for the open-floor robot"); 3 imitation epochs and 4
    # validations to fit an hour on 2 cores of an AVX2 machine; the finished model searches two steps, the best 8
    # actions deeper ("A narrower deeper search"), with V capped
    "apg_robust": Variant("ApgPolicy", env_id="CrowdNavWorlds-v0", env_kwargs={"worlds": "robust", "actions": "with_stop"},
                          schedule={"train_freq": 8, "num_humans": (0, 10), "rl_episodes": 3_000,
                                    "exploration_episodes": 1_500, "imitation_epochs": 3, "checkpoint_episodes": 750,
                                    "planning_depth": 2, "planning_width": 8, "cap_values": True}),
}


def describe_default(key: str) -> str:
    """The default of schedule setting ``key`` for the command line's help, read from :data:`PAPER_SCHEDULE` and
    :data:`VARIANTS`: ``"the variant's: 4; apg_rl, apg_warehouse, apg_robust: 8"`` (so the help cannot drift from the
    recipes)."""
    base = PAPER_SCHEDULE[key]
    others: dict[Any, list[str]] = {}
    for name, variant in VARIANTS.items():
        value = variant.schedule.get(key, base)
        if value != base:
            others.setdefault(value, []).append(name)
    parts = [f"{', '.join(names)}: {value}" for value, names in others.items()]
    return "; ".join([f"the variant's: {base}", *parts])
