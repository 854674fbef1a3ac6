"""The runner (same seeds → same records, in one process and in two), model loading, figures."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, PPO

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.evaluation import (
    TEST_SEED_OFFSET,
    RandomPolicy,
    detect_algorithm,
    discounted_return,
    load_model,
    plot_learning_curves,
    plot_trajectories,
    plot_value_map,
    run_episodes,
    run_sweep,
    save_animation,
)
from sb3_crowdnav.evaluation.plots import action_value_grid
from sb3_crowdnav.evaluation.policy_spec import GRAMMAR, PolicySpec
from sb3_crowdnav.evaluation.runner import make_policy, policy_label
from sb3_crowdnav.serialization import UnsafeModelFileError

torch.set_num_threads(1)
FAST = {"human_policy": "linear", "num_humans": 4}


def test_same_seeds_same_records_and_documented_seed_range():
    a = run_episodes("orca", 4, FAST, keep_trajectories=True)
    b = run_episodes("orca", 4, FAST, keep_trajectories=True)
    assert a == b
    assert [r.seed for r in a] == [TEST_SEED_OFFSET + i for i in range(4)]
    assert {r.outcome for r in a} <= {"success", "collision", "timeout"}
    rec = a[0]
    assert rec.trajectory.robot.shape == (rec.steps + 1, 9)
    assert rec.trajectory.humans.shape == (rec.steps + 1, rec.num_humans, 5)
    assert rec.navigation_time == pytest.approx(rec.steps * 0.25)
    # explicit seeds in another order give the same records
    c = run_episodes("orca", seeds=[TEST_SEED_OFFSET + 2, TEST_SEED_OFFSET], env_kwargs=FAST, keep_trajectories=True)
    assert c == [a[2], a[0]]
    # the random policy is re-seeded per episode: independent of order too
    r = run_episodes("random", 3, FAST)
    assert run_episodes("random", seeds=[TEST_SEED_OFFSET + 2], env_kwargs=FAST) == [r[2]]
    assert run_episodes("random:1", 3, FAST) != r


def test_record_matches_a_hand_played_episode():
    env = gym.make("CrowdNav-v0", **FAST)
    policy = RandomPolicy(env.action_space, seed=0)
    seed = TEST_SEED_OFFSET + 5
    obs, _ = env.reset(seed=seed)
    policy.seed_episode(seed)
    rewards = []
    while True:
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, info = env.step(int(action))
        rewards.append(reward)
        if terminated or truncated:
            break
    rec = run_episodes(RandomPolicy(env.action_space, seed=0), seeds=[seed], env_kwargs=FAST)[0]
    assert rec.steps == len(rewards)
    assert rec.episode_return == pytest.approx(sum(rewards))
    assert rec.discounted_return == pytest.approx(discounted_return(rewards, 0.9, 0.25, 1.0))
    assert rec.outcome == info["outcome"]


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_one_process_equals_two(tmp_path):
    one = run_episodes("orca", 6, FAST, keep_trajectories=True)
    two = run_episodes("orca", 6, FAST, keep_trajectories=True, workers=2)
    assert one == two
    # a saved SB3 model, loaded in each worker
    env = gym.make("CrowdNav-v0", **FAST)
    DQN("MultiInputPolicy", env, seed=0, policy_kwargs={"net_arch": [16]}).save(tmp_path / "dqn_model.zip")
    path = str(tmp_path / "dqn_model.zip")
    assert run_episodes(path, 3, FAST) == run_episodes(path, 3, FAST, workers=2)


def test_workers_need_a_spec_and_bad_arguments():
    with pytest.raises(ValueError, match="spec"):
        run_episodes(RandomPolicy(80), 2, FAST, workers=2)
    with pytest.raises(ValueError):
        run_episodes("orca", 0)
    with pytest.raises(TypeError):
        run_episodes(object(), 1, FAST)
    with pytest.raises(FileNotFoundError):
        run_episodes("missing_model.zip", 1, FAST)


@pytest.mark.parametrize(("text", "kind", "argument", "label"), [
    ("orca", "orca", None, "ORCA"),
    (" ORCA-Constrained ", "orca-constrained", None, "ORCA-constrained"),
    ("random", "random", None, "Random"),
    ("Random:7", "random", "7", "Random"),
    ("pretrained:apg_rl", "pretrained", "apg_rl", "APG_RL"),
    ("runs/a/best_model.zip", "file", "runs/a/best_model.zip", "best_model"),
    ("C:/models/m.zip", "file", "C:/models/m.zip", "m"),  # a colon in a path is not a keyword
])
def test_policy_spec_grammar(text, kind, argument, label):
    spec = PolicySpec.parse(text)
    assert (spec.kind, spec.argument, spec.label) == (kind, argument, label)
    assert PolicySpec.parse(str(spec)) == spec
    assert policy_label(text) == label


@pytest.mark.parametrize("text", ["", "  ", "random:", "random:-1", "random:x", "random:1.5", "pretrained:"])
def test_policy_spec_refuses_text_off_the_grammar(text):
    with pytest.raises(ValueError, match="policy") as caught:
        PolicySpec.parse(text)
    assert "random:SEED" in str(caught.value) or GRAMMAR in str(caught.value)
    with pytest.raises(ValueError, match="--policy"):  # the caller's name for the parameter
        PolicySpec.parse(text, name="--policy")


def test_the_runner_reads_specs_with_the_grammar():
    env = gym.make("CrowdNav-v0", **FAST)
    policy = make_policy("random:7", env)
    assert isinstance(policy, RandomPolicy) and policy.seed == 7
    assert make_policy(PolicySpec("orca-constrained"), env).mapping == "constrained"
    with pytest.raises(ValueError, match="random:SEED"):
        run_episodes("random:-1", 1, FAST)
    with pytest.raises(TypeError, match="policy"):
        PolicySpec.parse(3)
    assert run_episodes(PolicySpec("random", "3"), 2, FAST) == run_episodes("random:3", 2, FAST, workers=2)


def test_sweep_sets_the_number_of_pedestrians():
    out = run_sweep("random", [1, 3], 2, {"human_policy": "linear"})
    assert sorted(out) == [1, 3]
    assert all(r.num_humans == n for n, recs in out.items() for r in recs)


def test_load_model_detects_the_algorithm(tmp_path):
    env = gym.make("CrowdNav-v0", **FAST)
    obs, _ = env.reset(seed=0)
    for cls, name, kw in ((DQN, "dqn", {}), (PPO, "ppo", {"n_steps": 32, "batch_size": 32})):
        model = cls("MultiInputPolicy", env, seed=0, policy_kwargs={"net_arch": [16]}, **kw)
        model.save(tmp_path / name)
        assert detect_algorithm(tmp_path / f"{name}.zip") == name
        with pytest.raises(UnsafeModelFileError, match="entry 'observation_space'"):  # SB3 pickled the spaces
            load_model(tmp_path / name)
        loaded = load_model(tmp_path / name, spaces_from=env)  # suffix optional; the env's spaces, shapes checked
        assert type(loaded) is cls
        assert loaded.predict(obs, deterministic=True)[0] == model.predict(obs, deterministic=True)[0]
    (tmp_path / "junk.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3"):
        load_model(tmp_path / "junk.zip")


def test_figures_are_written(tmp_path):
    recs = run_episodes("orca", 2, FAST, keep_trajectories=True)
    rand = run_episodes("random", 1, FAST, keep_trajectories=True)
    png = plot_trajectories({"ORCA": recs[0], "Random": rand[0], "ORCA #2": recs[1].trajectory}, tmp_path / "t.png")
    assert png.stat().st_size > 1000
    gif = save_animation(recs[0], tmp_path / "e.gif")
    assert gif.stat().st_size > 1000
    with pytest.raises(ValueError, match="trajectory"):
        plot_trajectories({"x": run_episodes("orca", 1, FAST)[0]}, tmp_path / "u.png")
    with pytest.raises(ValueError):
        save_animation(recs[0], tmp_path / "e.avi")


class _FakeValuePolicy:
    def action_values(self, observation):
        b = observation["robot"].shape[0]
        return np.tile(np.arange(80, dtype=float), (b, 1))


class _FakeModel:
    policy = _FakeValuePolicy()


def test_value_map(tmp_path):
    env = gym.make("CrowdNav-v0", **FAST)
    obs, _ = env.reset(seed=0)
    values = plot_value_map(_FakeModel(), obs, tmp_path / "v.png", scene=env.unwrapped.scene)
    assert (tmp_path / "v.png").stat().st_size > 1000
    assert values.shape == (80,)
    speeds, angles, grid = action_value_grid(values, obs)
    assert np.allclose(speeds, [0.2, 0.4, 0.6, 0.8, 1.0])
    assert np.all(np.diff(angles) > 0) and grid.shape == (5, 16)
    # direction 0 (straight on) sits at the robot's heading (π/2 at the start)
    k = int(np.argmin(np.abs(angles - np.pi / 2)))
    assert grid[0, k] == 0.0 and grid[4, k] == 64.0
    with pytest.raises(TypeError, match="action_values"):
        plot_value_map(object(), obs, tmp_path / "w.png")


def test_learning_curves_from_tensorboard(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    for run, scale in (("PPO_1", 1.0), ("PPO_2", 0.5)):
        writer = SummaryWriter(str(tmp_path / "tb" / run))
        for step in range(5):
            writer.add_scalar("rollout/success_rate", scale * step / 4, step * 100)
            writer.add_scalar("rollout/ep_rew_mean", scale * step, step * 100)
        writer.close()
    path = plot_learning_curves(tmp_path / "tb", tmp_path / "curves.png")
    assert path.stat().st_size > 1000
    with pytest.raises(ValueError, match="none of the tags"):
        plot_learning_curves(tmp_path / "tb", tmp_path / "x.png", tags=("train/loss",))


def test_apg_value_model(tmp_path):
    from sb3_crowdnav.apg_value import APGValue

    env = gym.make("CrowdNav-v0", **FAST)
    model = APGValue("ApgPolicy", env, imitation_episodes=1, learning_starts=0, seed=0)
    model.save(tmp_path / "apg.zip")
    assert detect_algorithm(tmp_path / "apg.zip") == "apg_value"
    loaded = load_model(tmp_path / "apg.zip")
    assert type(loaded).__name__ == "APGValue"
    obs, _ = env.reset(seed=0)
    values = plot_value_map(loaded, obs, tmp_path / "v.png", scene=env.unwrapped.scene)
    assert values.shape == (80,)
    assert int(np.argmax(values)) == int(loaded.predict(obs, deterministic=True)[0])
    assert run_episodes(str(tmp_path / "apg.zip"), 2, FAST) == run_episodes(loaded, 2, FAST)


def test_model_with_other_capacity_is_refused(tmp_path):
    env = gym.make("CrowdNav-v0", **FAST)
    DQN("MultiInputPolicy", env, seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "m.zip")
    with pytest.raises(ValueError, match="max_humans"):
        run_episodes(str(tmp_path / "m.zip"), 1, {**FAST, "max_humans": 5})
    with pytest.raises(ValueError, match="max_humans"):  # checked before any worker starts
        run_episodes(str(tmp_path / "m.zip"), 2, {**FAST, "max_humans": 5}, workers=2)


@pytest.mark.slow  # a training run or a full CLI run: make slow
@pytest.mark.parametrize("spec", ["pretrained:apg_rl", "pretrained:ppo_apg"])
def test_stochastic_evaluation_is_the_same_with_one_or_two_workers(spec):
    """Each episode's sampled actions are seeded from its episode seed: the split across processes does not matter."""
    kwargs = dict(seeds=[1_000_000, 1_000_001, 1_000_002, 1_000_003], deterministic=False, env_kwargs={"num_humans": 3})
    one = run_episodes(spec, workers=1, **kwargs)
    two = run_episodes(spec, workers=2, **kwargs)
    assert one == two
    again = run_episodes(spec, workers=1, **{**kwargs, "seeds": kwargs["seeds"][::-1]})
    assert one == again[::-1]  # nor does their order


@pytest.mark.parametrize("env_id", ["CrowdNav-v0", "CrowdNavWarehouse-v0"])
def test_trajectory_legend_fits_a_single_panel(env_id, tmp_path, monkeypatch):
    from sb3_crowdnav.evaluation import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path, **kw: figures.append(fig) or path)
    record = run_episodes("orca", 1, {"num_humans": 2}, env_id=env_id, keep_trajectories=True)[0]
    plot_trajectories({"ORCA robot": record}, tmp_path / "one.png")
    fig = figures[0]
    renderer = fig.canvas.get_renderer()
    box, legend = fig.bbox, fig.legends[0].get_window_extent(renderer)
    assert box.x0 <= legend.x0 and legend.x1 <= box.x1 and box.y0 <= legend.y0, (legend, box)
    for ax in fig.axes:  # and the panel does not sit on the legend
        assert ax.get_tightbbox(renderer).y0 >= legend.y1 - 1


def test_lookahead_settings_reach_value_models_and_only_them():
    """make_policy's lookahead sets a value model's pedestrian model (in the parent and in a worker), V unchanged; a
    policy without a lookahead, an unknown key and a stopping check in a world without limits are refused."""
    from sb3_crowdnav.evaluation import runner

    env = gym.make("CrowdNav-v0")
    plain = make_policy("pretrained:apg_rl", env)
    cautious = make_policy("pretrained:apg_rl", env, lookahead={"pedestrian_model": "cautious"})
    assert plain.policy.pedestrian_model == "constant_velocity" and cautious.policy.pedestrian_model == "cautious"
    for a, b in zip(plain.policy.state_dict().values(), cautious.policy.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    runner._init_worker(PolicySpec.parse("pretrained:apg_rl"), "CrowdNav-v0", {}, 1,
                        lookahead={"pedestrian_model": "cautious"})
    assert runner._WORKER["policy"].policy.pedestrian_model == "cautious"
    with pytest.raises(ValueError, match="value model"):
        make_policy("orca", env, lookahead={"pedestrian_model": "cautious"})
    with pytest.raises(ValueError, match="lookahead takes"):
        make_policy("pretrained:apg_rl", env, lookahead={"horizon": 2})
    with pytest.raises(ValueError, match="stopping"):
        make_policy("pretrained:apg_rl", env, lookahead={"stopping_check": True})


def test_the_cautious_lookahead_changes_decisions_in_a_crossing(tmp_path):
    """--pedestrian-model reaches the episodes: a value model acting with the cautious model decides differently in at
    least one of these episodes, and the run's meta.json records the setting."""
    import json

    from sb3_crowdnav.cli import main

    outs = {}
    for name, extra in (("plain", []), ("cautious", ["--pedestrian-model", "cautious"])):
        out = tmp_path / name
        assert main(["evaluate", "--policy", "pretrained:apg_rl", "--episodes", "6", "--out", str(out), "--no-progress",
                     *extra]) == 0
        outs[name] = out
    read = {name: (out / "episodes.csv").read_text() for name, out in outs.items()}
    assert read["plain"] != read["cautious"]
    assert json.loads((outs["cautious"] / "meta.json").read_text())["lookahead"] == {"pedestrian_model": "cautious"}
    assert json.loads((outs["plain"] / "meta.json").read_text())["lookahead"] is None


@pytest.mark.parametrize("algo", ["ppo", "dqn", "maskableppo"])
def test_a_zoo_model_that_imitated_is_detected_as_its_own_algorithm(tmp_path, algo):
    """The zoo's algorithms save imitation_episodes too (ImitationMixin): it does not make a file APGValue's."""
    from sb3_contrib import MaskablePPO

    from sb3_crowdnav.training.zoo import ZOO_ALGOS

    base = {"ppo": PPO, "dqn": DQN, "maskableppo": MaskablePPO}[algo]
    env = gym.make("CrowdNavWarehouse-v0", num_humans=2) if algo == "maskableppo" else gym.make("CrowdNav-v0", **FAST)
    kw = {} if algo == "dqn" else {"n_steps": 32, "batch_size": 32}
    ZOO_ALGOS[algo]("ApgPolicy", env, imitation_episodes=3, seed=0, **kw).save(tmp_path / algo)
    assert detect_algorithm(tmp_path / f"{algo}.zip") == algo
    assert isinstance(load_model(tmp_path / f"{algo}.zip", spaces_from=env), base)
