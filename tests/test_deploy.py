"""sb3_crowdnav.deploy: the lookahead in torch equals the numpy one; the graph's contract is read strictly; OnnxPolicy
refuses what does not fit it; export round trips (slow: torch's exporter takes tens of seconds per model)."""

from __future__ import annotations

import functools
import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from lookahead_helpers import random_observations, value_policy

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.deploy.graph import LookaheadDecision, decision_module
from sb3_crowdnav.deploy.metadata import FORMAT, PREFIX, GraphMetadata
from sb3_crowdnav.deploy.propagation import atan2, wrap
from sb3_crowdnav.sim.actions import wrap_angle
from sb3_crowdnav.sim.observation import ObservationSchema, Robot
from sb3_crowdnav.sim.world import World

WAREHOUSE_PAPER = dict(actions="paper", max_acceleration=None, max_turn_rate=None)
# (env id, env kwargs, policy kwargs): every branch of the propagation and the reward
WORLDS = {
    "open floor": ("CrowdNav-v0", {}, {}),
    "comfort_angular, cautious": ("CrowdNav-v0", {"reward": "comfort_angular"}, {"pedestrian_model": "cautious"}),
    "comfort, ensemble": ("CrowdNav-v0", {"reward": "comfort"}, {"ensemble_size": 2}),
    "limits and a stop": ("CrowdNav-v0", {"actions": "with_stop", "max_acceleration": 1.0, "max_turn_rate": 2.0}, {}),
    "holonomic, limited": ("CrowdNav-v0", {"kinematics": "holonomic", "max_acceleration": 1.5}, {}),
    "holonomic, narrow fan": ("CrowdNav-v0", {"kinematics": "holonomic", "rotation_range": math.pi}, {}),
    "open floor, goal progress": ("CrowdNav-v0", {"progress_reward": 0.1}, {}),
    "comfort, goal progress, cautious": ("CrowdNav-v0", {"reward": "comfort", "progress_reward": 1.0},
                                         {"pedestrian_model": "cautious"}),
    "warehouse": ("CrowdNavWarehouse-v0", {"progress_reward": 0.1}, {"pedestrian_model": "cautious"}),
    "warehouse, limits": ("CrowdNavWarehouse-v0", {}, {}),
    "warehouse, stopping check": ("CrowdNavWarehouse-v0", {}, {"stopping_check": True}),
    "warehouse, stopping check, cautious": ("CrowdNavWarehouse-v0", {"progress_reward": 0.1},
                                            {"pedestrian_model": "cautious", "stopping_check": True}),
    "limits and a stop, stopping check": ("CrowdNav-v0", {"actions": "with_stop", "max_acceleration": 1.0,
                                                          "max_turn_rate": 2.0}, {"stopping_check": True}),
    "holonomic, limited, stopping check": ("CrowdNav-v0", {"kinematics": "holonomic", "max_acceleration": 1.5},
                                           {"stopping_check": True}),
}


def test_wrap_and_atan2_are_the_numpy_ones():
    angles = np.concatenate([np.linspace(-20, 20, 2001), [math.pi, -math.pi, 3 * math.pi, 0.0, -0.0]])
    np.testing.assert_array_equal(wrap(th.as_tensor(angles)).numpy(), wrap_angle(angles))
    rng = np.random.default_rng(0)
    y, x = rng.normal(size=(2, 5000)) * rng.choice([1e-3, 1.0, 1e3], size=(2, 5000))
    x[:3], y[:3] = [0.0, -1.0, -1.0], [0.0, 0.0, -0.0]
    np.testing.assert_allclose(atan2(th.as_tensor(y), th.as_tensor(x)).numpy(), np.arctan2(y, x), rtol=0, atol=1e-15)


SLOW_WORLDS = ("warehouse, stopping check", "holonomic, limited, stopping check")  # 200 observations each: make slow


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW_WORLDS else c for c in WORLDS])
def test_the_graph_decision_is_the_policys(case, monkeypatch):
    """The torch propagation, reward and value ceiling give the numpy lookahead's values on real observations."""
    env_id, env_kwargs, policy_kwargs = WORLDS[case]
    env = gym.make(env_id, **env_kwargs)
    policy = value_policy(env, **policy_kwargs)
    obs = random_observations(env, 200 if policy.stopping_check else 40)  # enough for the check to charge some actions
    # the graph takes the batch in one pass: so does the policy here (it searches ACTION_VALUE_CHUNK at a time)
    monkeypatch.setattr(policy, "ACTION_VALUE_CHUNK", len(obs["robot"]))
    distinct = policy.action_values(obs)  # under limits V once per distinct state: other batch sizes, float32 rounding
    # the graph evaluates V on every (observation, action) row, as the policy does when told to
    monkeypatch.setattr(policy, "lookahead_inputs", functools.partial(policy.lookahead_inputs, distinct=False))
    expected = policy.action_values(obs)
    np.testing.assert_allclose(distinct, expected, rtol=0, atol=1e-6)
    with th.no_grad():
        action, values = LookaheadDecision(policy).eval()({k: th.as_tensor(v) for k, v in obs.items()})
    np.testing.assert_allclose(values.numpy(), expected, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(action.numpy(), expected.argmax(axis=1))
    prop = policy.propagation(obs["robot"], obs["humans"], obs["humans_mask"],
                              {k: obs[k] for k in ("obstacles", "obstacles_mask", "waypoints") if k in obs})
    graph = LookaheadDecision(policy).propagation({k: th.as_tensor(v) for k, v in obs.items()})
    np.testing.assert_array_equal(graph.terminal.numpy(), prop.terminal)  # every collision, success and wall hit
    np.testing.assert_allclose(graph.reward.numpy(), prop.reward, rtol=0, atol=1e-12)
    if policy.stopping_check:  # the check charged something here, and the graph charged the same
        policy.set_stopping_check(False)
        unchecked = LookaheadDecision(policy).propagation({k: th.as_tensor(v) for k, v in obs.items()})
        assert (graph.terminal.numpy() & ~unchecked.terminal.numpy()).any()


def test_unsupported_models_are_refused_by_name():
    from sb3_contrib import QRDQN, RecurrentPPO
    from stable_baselines3 import PPO

    from sb3_crowdnav.nn import ApgRecurrentPolicy

    env = gym.make("CrowdNav-v0")
    with pytest.raises(ValueError, match=r"QRDQN \(MultiInputPolicy\) encodes the observation with CombinedExtractor"):
        decision_module(QRDQN("MultiInputPolicy", env, learning_starts=0, buffer_size=10))
    with pytest.raises(ValueError, match="CombinedExtractor"):
        decision_module(PPO("MultiInputPolicy", env, n_steps=8, batch_size=8))
    recurrent = RecurrentPPO(ApgRecurrentPolicy, env, n_steps=8, batch_size=8, policy_kwargs=dict(lstm_hidden_size=4))
    with pytest.raises(ValueError, match=r"RecurrentPPO \(ApgRecurrentPolicy\) cannot be exported: .*LSTM state"):
        decision_module(recurrent)
    with pytest.raises(ValueError, match="Linear cannot be exported"):
        decision_module(th.nn.Linear(2, 2))


def _contrib_models():
    """A freshly initialised QR-DQN (open floor) and MaskablePPO (warehouse, wall masks) with the APG encoder."""
    from sb3_contrib import QRDQN, MaskablePPO

    from sb3_crowdnav.apg_value.action_masks import WallActionMasker
    from sb3_crowdnav.nn import ApgMaskablePolicy, ApgQRDQNPolicy

    env, warehouse = gym.make("CrowdNav-v0"), gym.make("CrowdNavWarehouse-v0")
    qrdqn = QRDQN(ApgQRDQNPolicy, env, seed=0, buffer_size=10, learning_starts=0, policy_kwargs=dict(n_quantiles=8))
    maskable = MaskablePPO(ApgMaskablePolicy, WallActionMasker(warehouse), seed=0, n_steps=8, batch_size=8)
    return {"qrdqn": (qrdqn, env), "maskableppo": (maskable, warehouse)}


def _masks(model, obs: dict[str, np.ndarray], seed: int = 0) -> np.ndarray:
    """Random action masks, every row with an allowed action, and the unmasked greedy action masked in half the rows."""
    rng = np.random.default_rng(seed)
    masks = rng.random((len(obs["robot"]), model.action_space.n)) < 0.5
    masks[np.arange(len(masks)), rng.integers(model.action_space.n, size=len(masks))] = True
    greedy = model.predict(obs, deterministic=True)[0]
    half = np.arange(len(masks)) % 2 == 0
    masks[half, greedy[half]] = False
    masks[half & ~masks.any(axis=1), (greedy[half & ~masks.any(axis=1)] + 1) % model.action_space.n] = True
    return masks


@pytest.mark.parametrize("algo", ["qrdqn", "maskableppo"])
def test_the_contrib_decisions_act_as_their_models(algo):
    """QR-DQN: argmax of the mean over the quantiles; MaskablePPO: argmax of the masked logits, as their predict."""
    model, env = _contrib_models()[algo]
    obs = random_observations(env, 120)
    decision = decision_module(model).eval()
    tensors = {k: th.as_tensor(v) for k, v in obs.items()}
    with th.no_grad():
        if algo == "qrdqn":
            actions = decision(tensors)[0].numpy()
            np.testing.assert_array_equal(actions, model.predict(obs, deterministic=True)[0])
            return
        masks = _masks(model, obs)
        actions, values = decision(tensors, th.as_tensor(masks))
    expected = model.predict(obs, deterministic=True, action_masks=masks)[0]
    assert (expected != model.predict(obs, deterministic=True)[0]).sum() >= len(expected) // 2  # the masks matter
    np.testing.assert_array_equal(actions.numpy(), expected)
    assert (values.numpy()[~masks] == -1e8).all()


def test_export_refuses_before_any_work(tmp_path):
    """A model without a world, a world= that contradicts the model's, an env of another world: refused at once."""
    from stable_baselines3 import PPO

    from sb3_crowdnav.deploy import export_onnx
    from sb3_crowdnav.models import pretrained
    from sb3_crowdnav.nn import ApgActorCriticPolicy

    env = gym.make("CrowdNav-v0")
    with pytest.raises(ValueError, match="holds no world: pass world="):
        export_onnx(PPO(ApgActorCriticPolicy, env, n_steps=8, batch_size=8), tmp_path / "ppo.onnx")
    with pytest.raises(ValueError, match=r"world= differs .*time_step=0.25 \(world= has 0.5\)"):
        export_onnx(value_policy(env), tmp_path / "apg.onnx", world=World(time_step=0.5))
    with pytest.raises(ValueError, match=r"actions='paper' \(the env has 'with_stop'\)"):
        export_onnx(pretrained("apg_warehouse_paper"), tmp_path / "wh.onnx", env=gym.make("CrowdNavWarehouse-v0"))
    with pytest.raises(ValueError, match="trained on observations"):
        export_onnx(value_policy(env), tmp_path / "apg.onnx", env=gym.make("CrowdNav-v0", max_humans=7))
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- the contract
def _metadata(**kwargs) -> GraphMetadata:
    args = dict(kind="q_values", world=World(), schema=ObservationSchema(5, 10), robot_radius=0.3, robot_v_pref=1.0,
                policy="ApgDQNPolicy", extractor="ApgExtractor")
    return GraphMetadata(**{**args, **kwargs})


@pytest.mark.parametrize("meta", [
    _metadata(),
    _metadata(kind="lookahead", gamma=0.9, pedestrian_model="cautious", ensemble_size=2, planning_depth=1,
              world=World(actions="with_stop", max_acceleration=1.0, max_turn_rate=2.0)),
    _metadata(kind="lookahead", gamma=0.9, pedestrian_model="constant_velocity", braking_steps=5, planning_depth=2,
              world=World(actions="with_stop", max_acceleration=1.0, max_turn_rate=2.0)),
    _metadata(schema=ObservationSchema(5, 10, 16, 3), world=World(obstacle_collision_penalty=-0.25, waypoint_radius=0.6)),
])
def test_metadata_round_trips_as_plain_json(meta):
    props = meta.props()
    assert all(key.startswith(PREFIX) and isinstance(json.loads(text), object) for key, text in props.items())
    assert GraphMetadata.from_props(props) == meta
    actions = json.loads(props[PREFIX + "actions"])
    assert len(actions["speed_fractions"]) == meta.world.n_actions == actions["n_actions"]


def _edited(entry: str, edit) -> dict[str, str]:
    props = _metadata().props()
    value = json.loads(props[PREFIX + entry])
    props[PREFIX + entry] = edit(value) if callable(edit) else edit
    return props


@pytest.mark.parametrize("props, fragment", [
    ({k: v for k, v in _metadata().props().items() if not k.endswith("world")}, "lacks"),
    (_edited("world", "{'time_step': 0.25}"), "not plain JSON"),
    (_edited("robot", '{"radius": NaN}'), "not plain JSON"),
    (_edited("format", str(FORMAT + 1)), "update sb3_crowdnav"),
    (_edited("decision", lambda d: json.dumps({**d, "braking_steps": 4})), "braking_steps is set for a lookahead"),
    (_edited("decision", lambda d: json.dumps({k: v for k, v in d.items() if k != "braking_steps"})), "decision must"),
    (_edited("world", lambda w: json.dumps({**w, "time_step": 0.5})), "robot does not match the world"),
    (_edited("world", lambda w: json.dumps({**w, "warp_drive": True})), "warp_drive"),
    (_edited("actions", lambda a: json.dumps({**a, "directions": a["directions"][::-1]})), "action table"),
    (_edited("observation", lambda o: json.dumps({**o, "max_humans": 7})), "does not match its own schema"),
    (_edited("decision", lambda d: json.dumps({**d, "kind": "magic"})), "kind"),
    (_edited("robot", lambda r: json.dumps({**r, "radius": -1})), "robot_radius"),
])
def test_a_damaged_contract_is_refused_naming_the_entry(props, fragment):
    with pytest.raises(ValueError, match=fragment):
        GraphMetadata.from_props(props)


def test_a_format_1_contract_reads_as_a_graph_without_the_stopping_check():
    """Graphs written before the stopping check (format 1) have no braking_steps: they read as graphs without it."""
    props = _metadata().props()
    decision = json.loads(props[PREFIX + "decision"])
    del decision["braking_steps"]
    props[PREFIX + "decision"], props[PREFIX + "format"] = json.dumps(decision), "1"
    assert GraphMetadata.from_props(props).braking_steps is None
    with pytest.raises(ValueError, match="decision must"):  # a format-2 file must have it
        GraphMetadata.from_props({**props, PREFIX + "format": "2"})


def test_a_format_2_contract_reads_as_a_one_step_lookahead():
    """Graphs written before deeper searches (formats 1 and 2) have no planning_depth: a lookahead of one step."""
    meta = _metadata(kind="lookahead", gamma=0.9, pedestrian_model="constant_velocity", planning_depth=1)
    props = meta.props()
    decision = json.loads(props[PREFIX + "decision"])
    del decision["planning_depth"]
    props[PREFIX + "decision"], props[PREFIX + "format"] = json.dumps(decision), "2"
    assert GraphMetadata.from_props(props) == meta
    with pytest.raises(ValueError, match="decision must"):  # a format-3 file must have it
        GraphMetadata.from_props({**props, PREFIX + "format": "3"})
    with pytest.raises(ValueError, match="planning_depth is set for a lookahead only"):
        _metadata(planning_depth=1)
    with pytest.raises(ValueError, match="planning_depth must be >= 1"):
        _metadata(kind="lookahead", gamma=0.9, pedestrian_model="constant_velocity", planning_depth=0)


# ---------------------------------------------------------------- OnnxPolicy on a graph built by hand (fast)
def _toy_graph(path, meta: GraphMetadata | None = None, inputs: dict | None = None, masked: bool = False):
    """A graph of the deploy layout: action_values = robot @ W, action = argmax; ``masked``: a MaskablePPO-like graph,
    action_values = where(action_masks, robot @ W, -1e8), the mask a second input."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper, numpy_helper

    meta = meta or (_metadata(kind="masked_logits", policy="ApgMaskablePolicy") if masked else _metadata())
    n = meta.world.n_actions
    weights = np.random.default_rng(0).normal(size=(9, n)).astype(np.float32)
    shapes = inputs or meta.schema.shapes
    graph_inputs = [helper.make_tensor_value_info(k, TensorProto.FLOAT, ["batch", s[0]]) for k, s in shapes.items()]
    initializer = [numpy_helper.from_array(weights, "w")]
    nodes = [helper.make_node("MatMul", ["robot", "w"], ["logits" if masked else "action_values"])]
    if masked:
        graph_inputs.append(helper.make_tensor_value_info("action_masks", TensorProto.BOOL, ["batch", n]))
        initializer.append(numpy_helper.from_array(np.float32(-1e8), "masked"))
        nodes.append(helper.make_node("Where", ["action_masks", "logits", "masked"], ["action_values"]))
    nodes.append(helper.make_node("ArgMax", ["action_values"], ["action"], axis=1, keepdims=0))
    graph = helper.make_graph(
        nodes, "toy", graph_inputs,
        [helper.make_tensor_value_info("action", TensorProto.INT64, ["batch"]),
         helper.make_tensor_value_info("action_values", TensorProto.FLOAT, ["batch", n])],
        initializer=initializer)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    helper.set_model_props(model, meta.props())
    onnx.save_model(model, str(path))
    return weights


def test_onnx_policy_predicts_like_sb3(tmp_path):
    from sb3_crowdnav.deploy import OnnxPolicy

    weights = _toy_graph(tmp_path / "toy.onnx")
    env = gym.make("CrowdNav-v0")
    policy = OnnxPolicy(tmp_path / "toy.onnx", env)
    batch = random_observations(env, 5)
    actions, state = policy.predict(batch, state="kept")
    np.testing.assert_array_equal(actions, (batch["robot"] @ weights).argmax(axis=1))
    assert state == "kept"
    one, _ = policy.predict({k: v[0] for k, v in batch.items()})
    assert one.shape == () and one == actions[0]
    with pytest.raises(ValueError, match=r"missing \['humans_mask'\], unknown \['extra'\]"):
        policy.predict({"robot": batch["robot"], "humans": batch["humans"], "extra": 1})
    with pytest.raises(ValueError, match="observation shapes"):
        policy.predict({**batch, "humans": batch["humans"][:, :10]})
    with pytest.raises(ValueError, match=r"\(obs, info\)"):
        policy.predict(env.reset())
    with pytest.raises(ValueError, match="greedy"):
        policy.predict(batch, deterministic=False)


def test_onnx_policy_takes_action_masks_of_a_masked_graph(tmp_path):
    from sb3_crowdnav.deploy import OnnxPolicy

    weights = _toy_graph(tmp_path / "masked.onnx", masked=True)
    env = gym.make("CrowdNav-v0")
    policy = OnnxPolicy(tmp_path / "masked.onnx", env)
    batch = random_observations(env, 6)
    logits = batch["robot"] @ weights
    masks = np.ones_like(logits, dtype=bool)
    masks[np.arange(6), logits.argmax(axis=1)] = False  # the best action forbidden
    actions, _ = policy.predict(batch, action_masks=masks)
    np.testing.assert_array_equal(actions, np.where(masks, logits, -np.inf).argmax(axis=1))
    np.testing.assert_array_equal(policy.predict(batch)[0], logits.argmax(axis=1))  # no masks: every action allowed
    one, _ = policy.predict({k: v[0] for k, v in batch.items()}, action_masks=masks[0].astype(int))
    assert one == actions[0]
    with pytest.raises(ValueError, match=r"action_masks must have the shape \(6, 80\)"):
        policy.predict(batch, action_masks=masks[0])
    with pytest.raises(TypeError, match="booleans"):
        policy.predict(batch, action_masks=masks * 0.5)
    _toy_graph(tmp_path / "toy.onnx")
    with pytest.raises(ValueError, match=r"takes no action masks: .*ApgDQNPolicy"):
        OnnxPolicy(tmp_path / "toy.onnx").predict(batch, action_masks=masks)


def test_onnx_policy_refuses_another_world_naming_the_fields(tmp_path):
    from sb3_crowdnav.deploy import OnnxPolicy

    _toy_graph(tmp_path / "toy.onnx")
    with pytest.raises(ValueError, match=r"time_step=0.25 \(the env has 0.5\).*make the env with time_step=0.25"):
        OnnxPolicy(tmp_path / "toy.onnx", gym.make("CrowdNav-v0", time_step=0.5))
    OnnxPolicy(tmp_path / "toy.onnx", gym.make("CrowdNav-v0", time_step=0.5), allow_env_mismatch=True)
    with pytest.raises(ValueError, match=r"actions='paper' .*'with_stop'"):
        OnnxPolicy(tmp_path / "toy.onnx", gym.make("CrowdNav-v0", actions="with_stop"))
    with pytest.raises(ValueError, match="was trained on observations"):  # shapes are checked even then
        OnnxPolicy(tmp_path / "toy.onnx", gym.make("CrowdNav-v0", max_humans=7), allow_env_mismatch=True)


def test_onnx_policy_refuses_a_robot_faster_than_its_stopping_check_brakes(tmp_path):
    """A graph with the stopping check brakes for braking_steps sub-steps: 5 x 1 m/s² x 0.25 s = 1.25 m/s here. A
    robot whose velocity, or v_pref x the fastest action, is beyond that is refused, naming the observation's field."""
    from sb3_crowdnav.deploy import OnnxPolicy

    world = World(actions="with_stop", max_acceleration=1.0, max_turn_rate=2.0)
    meta = _metadata(kind="lookahead", gamma=0.9, pedestrian_model="constant_velocity", braking_steps=5, world=world,
                     planning_depth=1)
    assert meta.braking_speed == 1.25
    _toy_graph(tmp_path / "toy.onnx", meta)
    policy = OnnxPolicy(tmp_path / "toy.onnx")
    obs = {k: np.zeros((3, *s), dtype=np.float32) for k, s in meta.schema.shapes.items()}
    obs["robot"][:, Robot.V_PREF] = 1.0
    obs["robot"][:, Robot.VEL] = [[1.25, 0.0], [0.0, -1.2], [0.3, 0.4]]
    assert policy.predict(obs)[0].shape == (3,)
    obs["robot"][1, Robot.VEL] = [0.9, -0.9]  # 1.27 m/s
    with pytest.raises(ValueError, match=r"observation\['robot'\]: a speed of 1.273 m/s .* 1.250 m/s"):
        policy.predict(obs)
    obs["robot"][1, Robot.VEL], obs["robot"][2, Robot.V_PREF] = 0.0, 1.3
    with pytest.raises(ValueError, match=r"a speed of 1\.300 m/s"):
        policy.predict(obs)


def test_onnx_policy_refuses_a_graph_that_is_not_its_contract(tmp_path):
    from sb3_crowdnav.deploy import OnnxPolicy

    _toy_graph(tmp_path / "inputs.onnx", inputs={"robot": (9,), "humans": (250,)})
    with pytest.raises(ValueError, match="are not those of its metadata"):
        OnnxPolicy(tmp_path / "inputs.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not a graph")
    with pytest.raises(ValueError, match="not an ONNX graph"):
        OnnxPolicy(tmp_path / "junk.onnx")
    with pytest.raises(FileNotFoundError):
        OnnxPolicy(tmp_path / "missing.onnx")


def test_a_missing_runtime_says_how_to_install_it(tmp_path, monkeypatch):
    from sb3_crowdnav.deploy import OnnxPolicy

    _toy_graph(tmp_path / "toy.onnx")
    monkeypatch.setitem(__import__("sys").modules, "onnxruntime", None)  # as if not installed
    with pytest.raises(ImportError, match=r'pip install "sb3-crowdnav\[deploy\]"'):
        OnnxPolicy(tmp_path / "toy.onnx")


def test_the_runner_and_the_cli_run_a_graph(tmp_path, capsys):
    from sb3_crowdnav.cli import main
    from sb3_crowdnav.deploy import OnnxPolicy
    from sb3_crowdnav.evaluation.runner import make_policy, run_episodes

    path = tmp_path / "toy.onnx"
    _toy_graph(path)
    assert isinstance(make_policy(str(path), gym.make("CrowdNav-v0")), OnnxPolicy)
    records = run_episodes(str(path), 2)
    assert [r.seed for r in records] == [1_000_000, 1_000_001]
    assert main(["evaluate", "--policy", str(path), "--episodes", "2", "--no-progress"]) == 0
    assert "toy" in capsys.readouterr().out
    with pytest.raises(SystemExit) as caught:
        main(["evaluate", "--policy", str(path), "--episodes", "1", "--env-kwargs", "dict(time_step=0.5)"])
    err = capsys.readouterr().err
    assert caught.value.code == 2 and len(err.strip().splitlines()) == 1 and "time_step=0.25 (the env has 0.5)" in err


@pytest.mark.parametrize("args, fragment", [
    (["--policy", "orca", "--out", "x.onnx"], "is not a trained model"),
    (["--policy", "pretrained:nope", "--out", "x.onnx"], "unknown pretrained model"),
    (["--policy", "pretrained:apg_rl", "--out", "x.zip"], "--out must end in .onnx"),
    (["--policy", "model.onnx", "--out", "x.onnx"], "an exported graph already"),
    (["--policy", "missing.zip", "--out", "x.onnx"], "no saved model"),
    (["--policy", "pretrained:apg_rl", "--out", "x.onnx", "--env-kwargs", "dict(a=1)"], "--env-kwargs needs --env"),
    (["--policy", "pretrained:apg_rl", "--out", "x.onnx", "--env", "CartPole-v1"], "not a crowd-navigation env"),
])
def test_export_refuses_bad_input_in_one_line(tmp_path, capsys, monkeypatch, args, fragment):
    from sb3_crowdnav.cli import main

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as caught:
        main(["export", *args])
    err = capsys.readouterr().err
    assert caught.value.code == 2 and len(err.strip().splitlines()) == 1 and fragment in err, err


# ---------------------------------------------------------------- round trips through torch's exporter (slow)
@pytest.fixture(scope="module")
def graphs(tmp_path_factory):
    """The shipped open-floor and warehouse (an ensemble) models exported once for the tests below."""
    pytest.importorskip("onnxruntime")
    from sb3_crowdnav.deploy import export_onnx
    from sb3_crowdnav.models import check_pretrained

    folder = tmp_path_factory.mktemp("graphs")
    warehouse = gym.make("CrowdNavWarehouse-v0", **WAREHOUSE_PAPER)
    return {"apg_rl": export_onnx(check_pretrained("apg_rl"), folder / "apg_rl.onnx", env=gym.make("CrowdNav-v0")),
            "apg_warehouse_paper": export_onnx(check_pretrained("apg_warehouse_paper"), folder / "apg_warehouse.onnx",
                                         env=warehouse)}


def _assert_same_but_ties(actions: np.ndarray, values: np.ndarray) -> None:
    """The graph's actions are the argmax of the PyTorch values but where another action's value is within 1e-6."""
    rows = np.arange(len(actions))
    assert np.all(values.max(axis=1) - values[rows, actions] <= 1e-6)


def _assert_graph_matches(graph, policy, obs, atol: float) -> None:
    """The graph's values are the policy's within ``atol`` and its actions their argmax but for ties within 1e-6."""
    expected = policy.action_values(obs)
    actions, values, _ = graph.run(obs)
    np.testing.assert_allclose(values, expected, rtol=0, atol=atol)
    _assert_same_but_ties(actions, expected)


@pytest.mark.slow
@pytest.mark.parametrize("name, env_id, env_kwargs", [("apg_rl", "CrowdNav-v0", {}),
                                                     ("apg_warehouse_paper", "CrowdNavWarehouse-v0", WAREHOUSE_PAPER)])
def test_round_trip_of_a_shipped_model(graphs, name, env_id, env_kwargs):
    from sb3_crowdnav.deploy import OnnxPolicy
    from sb3_crowdnav.models import pretrained

    env = gym.make(env_id, **env_kwargs)
    model, graph = pretrained(name), OnnxPolicy(graphs[name], env)
    assert graph.metadata.ensemble_size == model.policy.ensemble_size
    obs = random_observations(env, 300, seed=1)
    _assert_graph_matches(graph, model.policy, obs, atol=1e-4)


@pytest.mark.slow
def test_round_trip_with_limits_a_stop_and_every_reward_term(tmp_path):
    """An untrained APG policy of a robot with limits and a stop, the cautious model and the comfort_angular reward
    (its sharp-turn threshold sits exactly on the table's ±π/2 turns: a float32 constant in the graph would flip it)."""
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx

    env = gym.make("CrowdNav-v0", reward="comfort_angular", actions="with_stop", max_acceleration=1.0,
                   max_turn_rate=8.0)
    policy = value_policy(env, pedestrian_model="cautious")
    graph = OnnxPolicy(export_onnx(policy, tmp_path / "limits.onnx", env=env), env)
    obs = random_observations(env, 200)
    _assert_graph_matches(graph, policy, obs, atol=1e-5)


@pytest.mark.slow
def test_round_trip_with_the_stopping_check(tmp_path):
    """An untrained APG policy acting with the stopping-distance check in the warehouse (cautious people): the graph
    brakes as the numpy lookahead, and its contract records the sub-steps."""
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx

    env = gym.make("CrowdNavWarehouse-v0")
    policy = value_policy(env, pedestrian_model="cautious", stopping_check=True)
    graph = OnnxPolicy(export_onnx(policy, tmp_path / "braking.onnx", env=env), env)
    assert graph.metadata.braking_steps == 5 and graph.metadata.braking_speed == 1.25
    obs = random_observations(env, 300)
    _assert_graph_matches(graph, policy, obs, atol=1e-5)
    policy.set_stopping_check(False)
    assert (policy.action_values(obs) != graph.action_values(obs)).any()  # the check is in the graph


@pytest.mark.slow
def test_round_trip_of_a_model_trained_with_goal_progress(tmp_path):
    """A model trained a few hundred steps on the open floor with the goal-progress shaping (the graph charges it and
    caps V at the ceiling, as the numpy lookahead): the graph's values are PyTorch's."""
    from sb3_crowdnav import APGValue
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx

    env = gym.make("CrowdNav-v0", progress_reward=0.1)
    model = APGValue("ApgPolicy", env, seed=0, imitation_episodes=2, imitation_epochs=1, batch_size=16,
                     buffer_size=2_000).learn(300)
    assert model.policy.world.progress_reward == 0.1 and model.policy.value_ceiling(np.ones(1)) is not None
    graph = OnnxPolicy(export_onnx(model, tmp_path / "progress.onnx", env=env), env)
    assert graph.metadata.world == model.policy.world
    obs = random_observations(env, 300, seed=1)
    _assert_graph_matches(graph, model.policy, obs, atol=1e-4)


def test_the_lstm_operator_is_the_eager_lstm():
    """The LSTM as one operator (what the graph holds) gives the eager extractors' last states, length 0 included."""
    from sb3_crowdnav.nn.layers import lstm_last_state, lstm_last_state_op

    th.manual_seed(0)
    lstm = th.nn.LSTM(4, 3, batch_first=True)
    sequence, lengths = th.randn(6, 5, 4), th.tensor([3, 0, 5, 1, 2, 5])
    with th.no_grad():
        op = lstm_last_state_op(sequence, lengths, lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0,
                                lstm.bias_hh_l0, 3)
        eager = lstm_last_state(lstm, sequence, lengths)
    th.testing.assert_close(th.where(lengths[:, None] > 0, op, 0.0), eager, rtol=0, atol=1e-6)
    assert th.equal(eager[1], th.zeros(3))


@pytest.mark.slow
@pytest.mark.parametrize("extractor", ["SfExtractor", "LmExtractor"])
def test_round_trip_of_several_observations_per_iteration(tmp_path, extractor):
    """Untrained SF and LM policies (LM's attention written in halves in a graph): their value network's Scan takes
    several observations per iteration, and batches that are not a multiple of it (padded with copies of the last
    observation) give the PyTorch values row for row."""
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx
    from sb3_crowdnav.deploy.export import observations_per_iteration
    from sb3_crowdnav.nn import extractors

    env = gym.make("CrowdNav-v0")
    policy = value_policy(env, features_extractor_class=getattr(extractors, extractor))
    per_iteration = observations_per_iteration(LookaheadDecision(policy), ObservationSchema.from_space(env.observation_space))
    assert per_iteration > 1
    graph = OnnxPolicy(export_onnx(policy, tmp_path / "sf.onnx", env=env), env)
    obs = random_observations(env, 2 * per_iteration + 1)
    obs["humans_mask"][1] = 0.0  # nobody present: an LSTM over no item
    empty = {**obs, "humans_mask": np.zeros_like(obs["humans_mask"])}  # nobody in the whole batch: one masked slot
    for count, source in ((1, obs), (per_iteration - 1, obs), (per_iteration, empty), (2 * per_iteration + 1, obs)):
        batch = {k: v[:count] for k, v in source.items()}
        expected = policy.action_values(batch)
        actions, values, _ = graph.run(batch)
        np.testing.assert_allclose(values, expected, rtol=0, atol=1e-5)
        _assert_same_but_ties(actions, expected)


@pytest.mark.slow
@pytest.mark.parametrize("name, env_id, env_kwargs", [("apg_rl", "CrowdNav-v0", {}),
                                                     ("apg_warehouse_paper", "CrowdNavWarehouse-v0", WAREHOUSE_PAPER)])
def test_evaluate_gives_the_records_of_the_original(graphs, tmp_path, capsys, name, env_id, env_kwargs):
    """``sb3-crowdnav evaluate`` writes the same episodes.csv, byte for byte, from the graph and from the model."""
    from sb3_crowdnav.cli import main

    options = ["--env", env_id, "--episodes", "3", "--seed-offset", "2000000", "--no-progress"]
    options += ["--env-kwargs", repr(env_kwargs)] if env_kwargs else []
    for tag, policy in (("model", f"pretrained:{name}"), ("graph", str(graphs[name]))):
        assert main(["evaluate", "--policy", policy, *options, "--out", str(tmp_path / tag)]) == 0
    capsys.readouterr()
    csv = (tmp_path / "model" / "episodes.csv").read_bytes()
    assert csv.count(b"\n") == 4 and (tmp_path / "graph" / "episodes.csv").read_bytes() == csv


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["qrdqn", "maskableppo"])
def test_round_trip_of_a_contrib_model(tmp_path, algo):
    """QR-DQN's and MaskablePPO's graphs act as the models' predict (MaskablePPO with and without masks), and
    ``evaluate`` of a MaskablePPO graph acts with the env's wall masks, as its model does."""
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx
    from sb3_crowdnav.evaluation.runner import run_episodes
    from sb3_crowdnav.serialization import write_spaces

    model, env = _contrib_models()[algo]
    graph = OnnxPolicy(export_onnx(model, tmp_path / f"{algo}.onnx", env=env), env)
    obs = random_observations(env, 300, seed=1)
    np.testing.assert_array_equal(graph.predict(obs)[0], model.predict(obs, deterministic=True)[0])
    if algo == "qrdqn":
        return
    masks = _masks(model, obs)
    actions, values, _ = graph.run(obs, masks)
    np.testing.assert_array_equal(actions, model.predict(obs, deterministic=True, action_masks=masks)[0])
    assert (values[~masks] == -1e8).all()
    model.save(tmp_path / "maskable.zip")
    write_spaces(tmp_path / "maskable.zip", model.observation_space, model.action_space, env)
    kwargs = dict(env_id="CrowdNavWarehouse-v0", seed_offset=2_000_000)
    original = run_episodes(str(tmp_path / "maskable.zip"), 2, **kwargs)
    assert [r.to_dict() for r in run_episodes(str(tmp_path / f"{algo}.onnx"), 2, **kwargs)] == \
        [r.to_dict() for r in original]


class _CrowdChoices(th.nn.Module):
    """The APG extractor's discrete choices: the pedestrians in the LSTM's order and the grid's sectors."""

    def __init__(self, extractor) -> None:
        super().__init__()
        self.extractor = extractor

    def forward(self, observation: dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        from sb3_crowdnav.nn import goal_frame_grid

        robot, humans, valid, _ = self.extractor._sorted_crowd(observation)
        grid = goal_frame_grid(robot, humans, valid, self.extractor.num_sectors, self.extractor.r_max)
        return th.where(valid[..., None], humans[:, -1, :, :2], 0.0), grid < self.extractor.r_max


def _edge_cases(env: gym.Env, count: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Observations whose pedestrians sit, in float32, on the grid's sector edges around each other (seen from the
    robot-to-goal axis) and at distances from the robot equal or 1 ulp apart."""
    from sb3_crowdnav.sim.observation import Human, Robot

    rng = np.random.default_rng(seed)
    obs = random_observations(env, count, seed)
    schema = ObservationSchema.from_space(env.observation_space)
    humans = schema.humans_view(obs["humans"].copy())  # (B, T, M, 5)
    robot = obs["robot"]
    goal_angle = np.arctan2(*(robot[:, Robot.GOAL] - robot[:, Robot.POS]).T[::-1])
    base = robot[:, None, Robot.POS] + rng.uniform(-3, 3, size=(count, 2)).astype(np.float32)[:, None]  # (B, 1, 2)
    edges = goal_angle[:, None] + 2 * np.pi * rng.integers(12, size=(count, 4)) / 12  # (B, 4)
    radius = rng.uniform(0.3, 2.5, size=(count, 4))
    people = np.concatenate([base, base + np.stack((radius * np.cos(edges), radius * np.sin(edges)), -1)], axis=1)
    people = people.astype(np.float32)  # (B, 5, 2): one pedestrian and four on edges around it
    offset = people[:, 1] - robot[:, Robot.POS]  # a sixth at the second's distance: mirrored, or 1 ulp off
    twin = robot[:, Robot.POS] + np.where(rng.random((count, 1)) < 0.5, offset[:, ::-1],
                                          np.nextafter(offset, np.float32(np.inf)))
    people = np.concatenate([people, twin[:, None].astype(np.float32)], axis=1)  # (B, 6, 2)
    humans[:, :, :6, Human.POS] = people[:, None]
    obs["humans"] = humans.reshape(count, -1)
    obs["humans_mask"][:, :6] = 1.0
    return obs


@pytest.mark.slow
def test_the_graph_makes_the_extractors_discrete_choices(tmp_path):
    """Pedestrians on sector edges and at (near-)equal distances: ONNX Runtime orders them and puts them in sectors as
    PyTorch does (a float32 atan2 or hypot kernel of either would differ there)."""
    ort = pytest.importorskip("onnxruntime")
    from sb3_crowdnav.deploy.export import _export
    from sb3_crowdnav.nn import ApgExtractor

    env = gym.make("CrowdNav-v0")
    schema = ObservationSchema.from_space(env.observation_space)
    module = _CrowdChoices(ApgExtractor(env.observation_space, (8,), (8, 4), (8, 1), 4))
    session = ort.InferenceSession(_export(module, schema, ("order", "occupied")).SerializeToString(),
                                   providers=["CPUExecutionProvider"])
    obs = _edge_cases(env, 400)
    with th.no_grad():
        order, occupied = module({k: th.as_tensor(v) for k, v in obs.items()})
    got = session.run(None, obs)
    np.testing.assert_array_equal(got[0], order.numpy())
    np.testing.assert_array_equal(got[1], occupied.numpy())


@pytest.mark.slow  # an export: make slow
def test_the_graph_caps_v_when_the_policy_does(tmp_path):
    """``cap_values=True`` on the paper's open floor (an overestimating V): the exported graph caps as the policy."""
    from sb3_crowdnav import APGValue
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx

    env = gym.make("CrowdNav-v0")
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    with th.no_grad():
        list(model.policy.value_net.parameters())[-1].add_(20.0)
    model.policy.set_cap_values(True)
    graph = OnnxPolicy(export_onnx(model, tmp_path / "capped.onnx", env=env), env)
    obs = random_observations(env, 100, seed=1)
    assert graph.run(obs)[1].max() <= 1.0 + 1e-5  # no action above the success reward
    _assert_graph_matches(graph, model.policy, obs, atol=1e-4)
