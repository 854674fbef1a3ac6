"""Metrics, tables and the restricted evaluator on hand-built records (no env)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from sb3_crowdnav.evaluation import EpisodeRecord, discounted_return, results_table, summarize, sweep_table, wilson_interval
from sb3_crowdnav.evaluation.tables import CSV_COLUMNS
from sb3_crowdnav.training.hyperparams import prepare, safe_eval


def record(seed, outcome, steps, time, ret, disc, sep, disc_freq, comfort=0.0, heading=0.0, path=0.0, humans=6):
    return EpisodeRecord(seed=seed, outcome=outcome, steps=steps, navigation_time=time, path_length=path,
                         episode_return=ret, discounted_return=disc, min_separation=sep,
                         discomfort_frequency=disc_freq, comfort_zone_time=comfort, heading_change=heading,
                         num_humans=humans)


def test_wilson_interval_hand_values():
    # 0 of 10: the upper bound is z²/(n + z²) exactly
    z2 = 1.959963984540054 ** 2
    assert wilson_interval(0, 10) == (0.0, pytest.approx(z2 / (10 + z2)))
    assert wilson_interval(10, 10) == (pytest.approx(10 / (10 + z2)), 1.0)
    # 1 of 4, by hand: p = 0.25, centre = (0.25 + z²/8) / (1 + z²/4), half = z/(1+z²/4)·sqrt(0.25·0.75/4 + z²/64)
    low, high = wilson_interval(1, 4)
    assert low == pytest.approx(0.0455873, abs=1e-6)
    assert high == pytest.approx(0.6993582, abs=1e-6)
    # the paper's 0.99 over 500 tests
    low, high = wilson_interval(495, 500)
    assert (low, high) == (pytest.approx(0.976807, abs=1e-6), pytest.approx(0.995721, abs=1e-6))
    assert all(math.isnan(x) for x in wilson_interval(0, 0))
    with pytest.raises(ValueError):
        wilson_interval(5, 4)


def test_discounted_return_hand_value():
    # 4 steps of Δt = 0.25 at v_pref = 1: exponents 0, 0.25, 0.5, 0.75
    rewards = [-0.01, 0.0, -0.02, 1.0]
    expected = -0.01 + 0.0 * 0.9 ** 0.25 - 0.02 * 0.9 ** 0.5 + 1.0 * 0.9 ** 0.75
    assert discounted_return(rewards, gamma=0.9, time_step=0.25, v_pref=1.0) == pytest.approx(expected)
    # success after 10.81 s with no other reward: 0.9^(10.81 - 0.25) ~ the paper's 0.32
    steps = round(10.81 / 0.25)
    assert discounted_return([0.0] * (steps - 1) + [1.0]) == pytest.approx(0.9 ** ((steps - 1) * 0.25))
    assert discounted_return([]) == 0.0


def test_summarize_hand_computed():
    recs = [
        record(0, "success", 40, 10.0, 1.0, 0.40, 0.10, 0.25, comfort=1.0, heading=2.0, path=9.0),
        record(1, "success", 48, 12.0, 0.9, 0.30, 0.30, 0.0, comfort=0.5, heading=1.0, path=11.0),
        record(2, "collision", 20, 5.0, -0.25, -0.20, -0.05, 0.5, comfort=2.0, heading=3.0, path=4.0),
        record(3, "timeout", 100, 25.0, 0.0, 0.0, math.inf, 0.0, humans=0),
    ]
    s = summarize(recs)
    assert s.episodes == 4
    assert s.success_rate == 0.5 and s.collision_rate == 0.25 and s.timeout_rate == 0.25
    assert s.success_ci == wilson_interval(2, 4)
    assert s.collision_ci == wilson_interval(1, 4)
    assert s.navigation_time == pytest.approx(11.0)  # successful episodes only
    assert s.path_length == pytest.approx(10.0)
    assert s.discounted_return == pytest.approx((0.40 + 0.30 - 0.20 + 0.0) / 4)
    assert s.episode_return == pytest.approx((1.0 + 0.9 - 0.25) / 4)
    assert s.min_separation == pytest.approx((0.10 + 0.30 - 0.05) / 3)  # the episode without pedestrians is left out
    assert s.discomfort_frequency == pytest.approx((10 + 0 + 10 + 0) / (40 + 48 + 20 + 100))  # pooled over steps
    assert s.comfort_zone_time == pytest.approx(3.5 / 4)
    assert s.heading_change == pytest.approx(6.0 / 4)


def test_in_zone_separations_are_pooled_over_steps():
    recs = [
        # 10 discomfort steps at a mean of 0.10 m; 4 comfort-zone steps (1.0 s) at a mean of 0.50 m
        replace(record(0, "success", 40, 10.0, 1.0, 0.4, 0.05, 0.25, comfort=1.0),
                discomfort_separation=0.10, comfort_zone_separation=0.50),
        # 2 discomfort steps at 0.16 m; 12 comfort-zone steps (3.0 s) at 0.30 m
        replace(record(1, "collision", 20, 5.0, -0.25, -0.2, -0.01, 0.1, comfort=3.0),
                discomfort_separation=0.16, comfort_zone_separation=0.30),
        # no such step: nan, left out
        record(2, "success", 36, 9.0, 1.0, 0.4, 0.9, 0.0, comfort=0.0),
    ]
    s = summarize(recs)
    assert s.discomfort_separation == pytest.approx((10 * 0.10 + 2 * 0.16) / 12)  # not (0.10 + 0.16) / 2
    assert s.comfort_zone_separation == pytest.approx((4 * 0.50 + 12 * 0.30) / 16)
    none = summarize([recs[2]])
    assert math.isnan(none.discomfort_separation) and math.isnan(none.comfort_zone_separation)
    row = results_table({"A": s}).rows[0]
    assert row["discomfort_gap"] == s.discomfort_separation and row["comfort_gap"] == s.comfort_zone_separation
    assert "gap in comfort zones (m)" in results_table({"A": s}).to_markdown()


def test_sharp_turns_are_averaged_over_all_episodes():
    recs = [replace(record(0, "success", 40, 10.0, 1.0, 0.4, 0.3, 0.0), sharp_turns=3),
            replace(record(1, "collision", 9, 2.0, -0.25, -0.2, -0.1, 0.2), sharp_turns=0),  # failures count too
            replace(record(2, "timeout", 100, 25.0, 0.0, 0.0, 0.5, 0.0), sharp_turns=12)]
    s = summarize(recs)
    assert s.sharp_turns == pytest.approx(5.0)
    table = results_table({"A": s})
    assert table.rows[0]["sharp_turns"] == pytest.approx(5.0)
    header, _, row = table.to_markdown().splitlines()
    assert header.rstrip(" |").endswith("sharp turns") and row.rstrip(" |").endswith("5.00")


def test_summarize_without_success_and_bad_input():
    s = summarize([record(0, "collision", 4, 1.0, -0.25, -0.25, -0.1, 1.0)])
    assert math.isnan(s.navigation_time) and s.collision_rate == 1.0
    with pytest.raises(ValueError):
        summarize([])
    with pytest.raises(ValueError, match="unknown outcome"):
        summarize([record(0, "running", 4, 1.0, 0, 0, 0, 0)])


def test_tables_markdown_and_csv(tmp_path):
    a = summarize([record(0, "success", 40, 10.0, 1.0, 0.4, 0.1, 0.0), record(1, "collision", 8, 2.0, -0.25, -0.2, -0.1, 0.5)])
    b = summarize([record(0, "timeout", 100, 25.0, 0.0, 0.0, 0.5, 0.0)])
    table = results_table({"ORCA": a, "Random": b})
    md = table.to_markdown()
    lines = md.strip().splitlines()
    assert lines[0].startswith("| method | success | collision | time (s) | return |")  # Table 3 order
    assert lines[2].startswith("| ORCA | 0.500 [")
    assert "| 10.00 | 0.1000 |" in lines[2]
    assert "| - |" in lines[3]  # no successful episode: no time
    md_path, csv_path = table.save(tmp_path / "results")
    assert md_path.read_text() == md
    rows = csv_path.read_text().splitlines()
    assert rows[0].split(",") == ["method", *CSV_COLUMNS]
    assert rows[1].split(",")[:2] == ["ORCA", "0.5"]
    sweep = sweep_table({6: a, 3: b})
    assert [r["humans"] for r in sweep.rows] == [3, 6]
    assert sweep.to_markdown().startswith("| humans |")


def test_safe_eval_allows_literals_dict_nn_and_names():
    import torch.nn as nn

    class Extractor:
        pass

    names = {"dict": dict, "nn": nn, "apg": Extractor}
    got = safe_eval("dict(net_arch=[64, 64], activation_fn=nn.ReLU, features_extractor_class=apg, lr=-1e-3 * 2)", names)
    assert got == {"net_arch": [64, 64], "activation_fn": nn.ReLU, "features_extractor_class": Extractor, "lr": -2e-3}
    assert safe_eval("{'a': (1, 2)}", names) == {"a": (1, 2)}
    for bad in ("__import__('os')", "open('x')", "nn.functional", "(1).__class__", "dict(**x)", "[x for x in []]",
                "2 ** 1000", "lambda: 0"):
        with pytest.raises(ValueError):
            safe_eval(bad, names)


def test_prepare_splits_zoo_hyperparams():
    cfg = prepare("ppo", {"n_timesteps": 2e5, "policy": "MultiInputPolicy", "policy_kwargs": "dict(net_arch=[32])",
                          "env_kwargs": {"num_humans": 3}, "n_envs": 2, "learning_rate": "lin_1e-3", "n_steps": 64})
    assert cfg["n_timesteps"] == 200_000 and cfg["n_envs"] == 2 and cfg["policy_kwargs"] == {"net_arch": [32]}
    assert cfg["env_kwargs"] == {"num_humans": 3}
    assert cfg["kwargs"]["n_steps"] == 64
    assert cfg["kwargs"]["learning_rate"](1.0) == pytest.approx(1e-3)
    assert cfg["kwargs"]["learning_rate"](0.5) == pytest.approx(5e-4)
    with pytest.raises(ValueError, match="VecNormalize"):
        prepare("ppo", {"normalize": True})
    with pytest.raises(ValueError):
        prepare("ppo", {"policy_kwargs": "dict(x=os.system)"})
    assert np.isfinite(cfg["kwargs"]["learning_rate"](0.0))


def test_records_with_nan_separations_compare_equal():
    a = record(0, "success", 40, 10.0, 1.0, 0.4, 0.5, 0.0)  # no discomfort step: nan separations
    assert math.isnan(a.discomfort_separation)
    assert a == record(0, "success", 40, 10.0, 1.0, 0.4, 0.5, 0.0)
    assert a != replace(a, discomfort_separation=0.1)
    assert a != replace(a, steps=41)
    assert a.__eq__("not a record") is NotImplemented


def test_a_record_from_the_envs_stats_takes_every_field_and_its_type():
    import gymnasium as gym

    from sb3_crowdnav.evaluation.records import RECORD_FIELDS, STATS_OPTIONAL

    env = gym.make("CrowdNav-v0")
    env.reset(seed=3)
    steps, total = 0, 0.0
    while True:
        _, reward, terminated, truncated, info = env.step(4 * 16)
        steps, total = steps + 1, total + float(reward)
        if terminated or truncated:
            break
    stats = info["episode_stats"]
    rec = EpisodeRecord.from_stats(3, steps, total, stats)
    for name in RECORD_FIELDS:
        if name not in ("seed", "steps", "episode_return") and name in stats:
            assert getattr(rec, name) == pytest.approx(stats[name], nan_ok=True) or getattr(rec, name) == stats[name]
    assert type(rec.num_humans) is int and type(rec.navigation_time) is float and type(rec.outcome) is str
    assert (rec.seed, rec.steps, rec.episode_return) == (3, steps, total)
    optional = {k: v for k, v in stats.items() if k not in STATS_OPTIONAL}  # the open floor's envs leave them out
    assert math.isnan(EpisodeRecord.from_stats(3, steps, total, optional).min_clearance)
    with pytest.raises(KeyError, match="near_misses"):  # a statistic every env reports is not made up
        EpisodeRecord.from_stats(3, steps, total, {k: v for k, v in stats.items() if k != "near_misses"})


def test_the_gap_leaves_out_episodes_in_which_no_one_was_present():
    # a recorded scene's window with people (num_humans 3) none of whom came while the robot drove: its separation is
    # the env's no-one distance, not a gap; a record without the count (-1, read from an older file) keeps num_humans
    present = replace(record(0, "success", 40, 10.0, 0.3, 0.3, 0.5, 0.0, humans=3), steps_with_people=12)
    nobody = replace(record(1, "success", 40, 10.0, 0.3, 0.3, 231.0, 0.0, humans=3), steps_with_people=0)
    older = record(2, "success", 40, 10.0, 0.3, 0.3, 1.5, 0.0, humans=3)
    assert older.steps_with_people == -1
    assert summarize([present, nobody]).min_separation == pytest.approx(0.5)
    assert summarize([present, nobody, older]).min_separation == pytest.approx(1.0)
    assert math.isnan(summarize([nobody]).min_separation)


@pytest.mark.parametrize("humans", [0, 6])
def test_the_env_counts_the_steps_with_someone_present(humans):
    import gymnasium as gym

    env = gym.make("CrowdNav-v0", num_humans=humans)
    env.reset(seed=5)
    steps = 0
    while True:
        *_, terminated, truncated, info = env.step(4 * 16)
        steps += 1
        if terminated or truncated:
            break
    assert info["episode_stats"]["steps_with_people"] == (steps if humans else 0)
