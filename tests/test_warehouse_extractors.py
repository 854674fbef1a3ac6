"""The static-world branch of the crowd encoders: warehouse-only, frame- and order-invariant, padding-blind."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.nn import EXTRACTORS
from sb3_crowdnav.nn.static_world import StaticWorldEncoder
from sb3_crowdnav.sim.observation import SEGMENT_DIM, ObservationSchema, Robot


@pytest.fixture(scope="module")
def warehouse():
    """The warehouse's space and a batch of its real observations (several seeds and steps)."""
    env = gym.make("CrowdNavWarehouse-v0")
    rows = []
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        rows.append(obs)
        for _ in range(3):
            obs, *_ = env.step(env.action_space.sample())
            rows.append(obs)
    space = env.observation_space
    env.close()
    batch = {k: th.as_tensor(np.stack([r[k] for r in rows])) for k in space.spaces}
    assert (batch["obstacles_mask"].sum(1) >= 2).all()  # every row sees walls: the tests below mean something
    assert (batch["obstacles_mask"] < 0.5).any()  # and some padding
    return space, batch


def _encoder(space, seed: int = 0) -> StaticWorldEncoder:
    th.manual_seed(seed)
    return StaticWorldEncoder(ObservationSchema.from_space(space)).eval()


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_open_floor_extractors_have_no_static_branch(name):
    space = gym.make("CrowdNav-v0").observation_space
    th.manual_seed(0)
    plain = EXTRACTORS[name](space)
    assert not hasattr(plain, "static_world")
    assert not any("static_world" in n for n, _ in plain.named_parameters())
    assert not plain._forward_hooks


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_warehouse_features_are_crowd_plus_static(name, warehouse):
    space, batch = warehouse
    th.manual_seed(0)
    model = EXTRACTORS[name](space).eval()
    static = model.static_world
    schema = ObservationSchema.from_space(space)
    assert static.features_dim == 32 + 2 * schema.num_waypoints
    with th.no_grad():
        out = model(batch)
    assert out.shape == (len(batch["robot"]), model.features_dim)
    assert th.isfinite(out).all()
    with th.no_grad():  # the tail is the static branch, the head the crowd encoder of the same observation
        np.testing.assert_allclose(out[:, -static.features_dim :], static(batch), atol=1e-6)
    crowd_space = gym.spaces.Dict({k: space[k] for k in ("robot", "humans", "humans_mask")})
    th.manual_seed(0)
    crowd = EXTRACTORS[name](crowd_space).eval()
    assert model.features_dim == crowd.features_dim + static.features_dim


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_gradients_reach_the_static_branch(name, warehouse):
    space, batch = warehouse
    model = EXTRACTORS[name](space).train()
    (model(batch) ** 2).sum().backward()
    for pname, param in model.static_world.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, pname
        assert th.isfinite(param.grad).all(), pname


def test_segment_order_does_not_matter(warehouse):
    space, batch = warehouse
    enc = _encoder(space)
    s = batch["obstacles_mask"].shape[1]
    perm = th.randperm(s, generator=th.Generator().manual_seed(1))
    permuted = dict(batch)
    permuted["obstacles"] = batch["obstacles"].view(-1, s, SEGMENT_DIM)[:, perm].reshape(-1, s * SEGMENT_DIM)
    permuted["obstacles_mask"] = batch["obstacles_mask"][:, perm]
    with th.no_grad():
        th.testing.assert_close(enc(batch), enc(permuted))


def test_padding_content_does_not_matter(warehouse):
    space, batch = warehouse
    enc = _encoder(space)
    s = batch["obstacles_mask"].shape[1]
    garbage = dict(batch)
    segments = batch["obstacles"].clone().view(-1, s, SEGMENT_DIM)
    padded = batch["obstacles_mask"] < 0.5
    noise = 100 * th.randn(segments.shape, generator=th.Generator().manual_seed(2))
    noise[..., 0] = th.nan
    segments[padded] = noise[padded]
    garbage["obstacles"] = segments.reshape(-1, s * SEGMENT_DIM)
    with th.no_grad():
        out = enc(garbage)
    assert th.isfinite(out).all()
    th.testing.assert_close(out, enc(batch))


def test_a_present_segment_matters_and_a_masked_one_does_not(warehouse):
    space, batch = warehouse
    enc = _encoder(space)
    s = batch["obstacles_mask"].shape[1]
    alone = dict(batch)  # the nearest segment alone (a max-pool may hide one segment among many)
    alone["obstacles_mask"] = th.zeros_like(batch["obstacles_mask"])
    alone["obstacles_mask"][:, 0] = 1.0
    moved = dict(alone)
    segments = batch["obstacles"].clone().view(-1, s, SEGMENT_DIM)
    segments[:, 0] = segments[:, 0] + 0.7
    moved["obstacles"] = segments.reshape(-1, s * SEGMENT_DIM)
    masked = dict(moved)
    masked["obstacles_mask"] = batch["obstacles_mask"].clone()
    masked["obstacles_mask"][:, 0] = 0.0  # the moved segment masked out among the others
    dropped = dict(batch)
    dropped["obstacles_mask"] = masked["obstacles_mask"]
    with th.no_grad():
        ref, out_moved = enc(alone), enc(moved)
        assert (out_moved - ref).abs().amax(dim=1).min() > 1e-4  # every row sees the move
        th.testing.assert_close(enc(masked), enc(dropped))  # masked out: its content is ignored


def test_no_segment_in_view_pools_to_zero(warehouse):
    space, batch = warehouse
    enc = _encoder(space)
    empty = dict(batch)
    empty["obstacles_mask"] = th.zeros_like(batch["obstacles_mask"])
    with th.no_grad():
        out = enc(empty)
    assert th.isfinite(out).all()
    assert (out[:, : enc.pooled_dim] == 0).all()


@pytest.mark.parametrize("angle", [0.3, 2.0, -2.9])
def test_rigid_motion_of_the_world_does_not_change_the_features(warehouse, angle):
    """Robot, goal, segments and waypoints rotated and shifted together: the robot-to-goal frame is the same."""
    space, batch = warehouse
    enc = _encoder(space)
    c, s_ = math.cos(angle), math.sin(angle)
    rot = th.tensor([[c, -s_], [s_, c]], dtype=batch["robot"].dtype)
    shift = th.tensor([3.0, -7.5], dtype=batch["robot"].dtype)

    def move(xy: th.Tensor) -> th.Tensor:
        return xy @ rot.T + shift

    n, s = batch["obstacles_mask"].shape
    moved = dict(batch)
    robot = batch["robot"].clone()
    robot[:, Robot.POS], robot[:, Robot.GOAL] = move(robot[:, Robot.POS]), move(robot[:, Robot.GOAL])
    robot[:, Robot.VEL] = robot[:, Robot.VEL] @ rot.T
    moved["robot"] = robot
    moved["obstacles"] = move(batch["obstacles"].view(n, 2 * s, 2)).reshape(n, -1)
    moved["waypoints"] = move(batch["waypoints"].view(n, -1, 2)).reshape(n, -1)
    with th.no_grad():
        th.testing.assert_close(enc(moved), enc(batch), atol=2e-4, rtol=1e-4)


@pytest.mark.parametrize("algo", ["DQN", "PPO"])
def test_sb3_learns_saves_and_loads_in_the_warehouse(algo, tmp_path):
    import stable_baselines3

    cls = getattr(stable_baselines3, algo)
    env = gym.make("CrowdNavWarehouse-v0")
    kwargs = dict(learning_starts=32, buffer_size=500, batch_size=16) if algo == "DQN" else dict(n_steps=64, batch_size=32)
    model = cls("MultiInputPolicy", env, policy_kwargs=dict(features_extractor_class=EXTRACTORS["apg"]), seed=0,
                **kwargs)
    model.learn(128)
    obs, _ = env.reset(seed=5)
    model.save(tmp_path / "model.zip")
    loaded = cls.load(tmp_path / "model.zip", device="cpu")
    assert any("static_world" in n for n, _ in loaded.policy.named_parameters())
    assert model.predict(obs, deterministic=True)[0] == loaded.predict(obs, deterministic=True)[0]


def test_apg_value_saves_and_loads_its_static_branch(tmp_path):
    from sb3_crowdnav import APGValue

    model = APGValue("ApgPolicy", "CrowdNavWarehouse-v0", imitation_episodes=0, seed=0)
    model.save(tmp_path / "warehouse.zip")
    loaded = APGValue.load(tmp_path / "warehouse.zip", env=gym.make("CrowdNavWarehouse-v0"))
    names = [n for n, _ in loaded.policy.named_parameters() if "static_world" in n]
    assert names  # the value net and its target both carry the branch
    for (n, a), (_, b) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items(), strict=True):
        th.testing.assert_close(a, b, msg=n)
    env = gym.make("CrowdNavWarehouse-v0")
    obs, _ = env.reset(seed=2)
    np.testing.assert_allclose(loaded.policy.action_values(obs), model.policy.action_values(obs), atol=1e-6)


def test_shipped_open_floor_model_is_unchanged_and_its_encoder_is_the_warehouse_crowd_part(warehouse):
    """apg_rl loads strictly (no new parameter), and its weights give the warehouse extractor the same crowd features."""
    from sb3_crowdnav import pretrained

    space, batch = warehouse
    plain = pretrained("apg_rl").policy.value_net.features_extractor.eval()
    assert not hasattr(plain, "static_world")
    th.manual_seed(0)
    model = EXTRACTORS["apg"](space).eval()
    missing, unexpected = model.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("static_world.") for k in missing)
    crowd = {k: batch[k] for k in ("robot", "humans", "humans_mask")}
    with th.no_grad():
        th.testing.assert_close(model(batch)[:, : plain.features_dim], plain(crowd))
