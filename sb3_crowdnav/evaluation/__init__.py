"""Evaluation harness: one runner for every policy, the paper's metrics, tables and figures.

Protocol: ``run_episodes(policy, 500)`` plays test episodes ``env.reset(seed=TEST_SEED_OFFSET + i)``
(``TEST_SEED_OFFSET = 1_000_000``, disjoint from the small training seeds), ``summarize`` turns the
records into rates with Wilson 95 % intervals and means, ``results_table`` into Markdown/CSV::

    from sb3_crowdnav.evaluation import run_episodes, summarize, results_table
    table = results_table({name: summarize(run_episodes(spec, 500, workers=2))
                           for name, spec in {"ORCA": "orca", "APG_RL": "apg_rl.zip"}.items()})
    print(table.to_markdown())
"""

from sb3_crowdnav.evaluation.metrics import Summary, discounted_return, summarize, wilson_interval
from sb3_crowdnav.evaluation.plots import (
    plot_learning_curves,
    plot_trajectories,
    plot_value_map,
    save_animation,
)
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import (
    TEST_SEED_OFFSET,
    EpisodeRecord,
    RandomPolicy,
    Trajectory,
    eval_seeds,
    make_policy,
    policy_label,
    run_episode,
    run_episodes,
    run_sweep,
)
from sb3_crowdnav.evaluation.tables import ResultsTable, results_table, sweep_table, write_records_csv
from sb3_crowdnav.models import algorithms, detect_algorithm, load_model

__all__ = [
    "TEST_SEED_OFFSET",
    "EpisodeRecord",
    "PolicySpec",
    "RandomPolicy",
    "ResultsTable",
    "Summary",
    "Trajectory",
    "algorithms",
    "detect_algorithm",
    "discounted_return",
    "eval_seeds",
    "load_model",
    "make_policy",
    "plot_learning_curves",
    "plot_trajectories",
    "plot_value_map",
    "policy_label",
    "results_table",
    "run_episode",
    "run_episodes",
    "run_sweep",
    "save_animation",
    "summarize",
    "sweep_table",
    "wilson_interval",
    "write_records_csv",
]
