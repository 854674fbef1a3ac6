"""Unit tests of the crowd encoders: transforms, APG, invariances, gradients, shapes."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.nn import (
    EXTRACTORS,
    ApgExtractor,
    HumanFeat,
    RobotFeat,
    angular_pedestrian_grid,
    layers,
    local_occupancy_map,
    parse_observation_space,
    robot_centric,
    social_forces,
)
from sb3_crowdnav.nn.interactions import sector_of
from sb3_crowdnav.nn.layers import set_onednn_inference, set_onednn_training
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Human, Robot

T, N = 5, 10


@pytest.fixture(scope="module")
def space():
    env = gym.make("CrowdNav-v0")
    obs_space = env.observation_space
    env.close()
    return obs_space


def polar(rho: float, deg: float) -> list[float]:
    return [rho * math.cos(math.radians(deg)), rho * math.sin(math.radians(deg))]


def random_obs(batch: int, n_present, seed: int = 0, spread: float = 4.0) -> dict[str, th.Tensor]:
    """Random valid observations; ``n_present`` is an int or one int per row (present slots are random)."""
    g = th.Generator().manual_seed(seed)
    robot = th.zeros(batch, ROBOT_DIM)
    robot[:, Robot.POS] = spread * (2 * th.rand(batch, 2, generator=g) - 1)
    robot[:, Robot.VEL] = th.randn(batch, 2, generator=g) * 0.5
    robot[:, Robot.RADIUS] = 0.3
    robot[:, Robot.GOAL] = spread * (2 * th.rand(batch, 2, generator=g) - 1)
    robot[:, Robot.V_PREF] = 1.0
    robot[:, Robot.HEADING] = (2 * th.rand(batch, generator=g) - 1) * math.pi
    humans = th.zeros(batch, T, N, HUMAN_DIM)
    humans[..., Human.POS] = spread * (2 * th.rand(batch, T, N, 2, generator=g) - 1)
    humans[..., Human.VEL] = th.randn(batch, T, N, 2, generator=g)
    humans[..., Human.RADIUS] = 0.2 + 0.2 * th.rand(batch, T, N, generator=g)
    counts = [n_present] * batch if isinstance(n_present, int) else list(n_present)
    mask = th.zeros(batch, N)
    for b, count in enumerate(counts):
        mask[b, th.randperm(N, generator=g)[:count]] = 1.0
    humans = th.where(mask[:, None, :, None] > 0.5, humans, 0.0)  # the env pads with zeros
    return {"robot": robot, "humans": humans.reshape(batch, -1), "humans_mask": mask}


def humans_view(obs: dict[str, th.Tensor]) -> th.Tensor:
    return obs["humans"].view(-1, T, N, HUMAN_DIM)


def make(name: str, space) -> th.nn.Module:
    th.manual_seed(0)
    return EXTRACTORS[name](space).eval()


# ----------------------------------------------------------------------------- transforms


def test_robot_centric_hand_computed():
    # robot at (1, 1) heading +y towards its goal (1, 5): the frame's x-axis is world +y, y-axis world -x
    robot = th.tensor([[1.0, 1.0, 0.0, 0.5, 0.3, 1.0, 5.0, 1.0, math.pi / 2]])
    humans = th.zeros(1, 1, 1, HUMAN_DIM)
    humans[0, 0, 0] = th.tensor([0.0, 1.0, 1.0, 0.0, 0.25])  # 1 m to the robot's left, walking world +x
    robot_feats, human_feats = robot_centric(robot, humans)
    assert robot_feats[0].tolist() == pytest.approx([4.0, 1.0, 0.5, 0.0, 0.3, 1.0, 0.0], abs=1e-6)
    h = human_feats[0, 0, 0]
    assert h[HumanFeat.POS].tolist() == pytest.approx([0.0, 1.0], abs=1e-6)  # left = +y
    assert h[HumanFeat.VEL].tolist() == pytest.approx([0.0, -1.0], abs=1e-6)  # world +x = the robot's right
    assert h[HumanFeat.RADIUS].item() == pytest.approx(0.25)
    assert h[HumanFeat.DIST].item() == pytest.approx(1.0)
    assert h[HumanFeat.RADIUS_SUM].item() == pytest.approx(0.55)


def test_robot_heading_relative_to_goal_axis():
    # goal straight along world -x (axis angle π), heading -π/2: relative heading +π/2
    robot = th.tensor([[0.0, 0.0, 0.0, 0.0, 0.3, -2.0, 0.0, 1.0, -math.pi / 2]])
    robot_feats, _ = robot_centric(robot, th.zeros(1, 1, 1, HUMAN_DIM))
    assert robot_feats[0, RobotFeat.HEADING].tolist() == pytest.approx([0.0, 1.0], abs=1e-6)


def test_robot_on_its_goal_is_finite():
    robot = th.tensor([[2.0, 2.0, 0.0, 0.0, 0.3, 2.0, 2.0, 1.0, 0.0]])
    robot_feats, human_feats = robot_centric(robot, th.zeros(1, 1, 1, HUMAN_DIM))
    assert th.isfinite(robot_feats).all() and th.isfinite(human_feats).all()
    assert robot_feats[0, RobotFeat.DIST_GOAL].item() == 0.0


# ----------------------------------------------------------------------------- APG (Eq. 3)


def test_apg_hand_computed_scene():
    # pedestrian 0 at the origin; sectors of 30°, sector 0 = [0°, 30°) from the x-axis, counter-clockwise
    positions = th.tensor([[
        [0.0, 0.0],
        polar(1.0, 15.0),  # sector 0
        polar(2.0, 100.0),  # sector 3
        polar(2.5, 110.0),  # sector 3 too, farther: not the minimum
        polar(5.0, 200.0),  # sector 6 but beyond r_max
        polar(0.5, 45.0),  # padded: must not appear (sector 1)
        polar(1.5, 315.0),  # sector 10
    ]])
    present = th.tensor([[True, True, True, True, True, False, True]])
    grid = angular_pedestrian_grid(positions, present, num_sectors=12, r_max=3.0)
    assert grid.shape == (1, 7, 12)
    expected0 = [3.0] * 12
    expected0[0], expected0[3], expected0[10] = 1.0, 2.0, 1.5
    assert grid[0, 0].tolist() == pytest.approx(expected0, abs=1e-5)
    # the padded pedestrian's own row is empty
    assert grid[0, 5].tolist() == pytest.approx([3.0] * 12)
    # pedestrian 6 at 1.5 m, 315°: the origin is at 135° from it (sector 4), pedestrian 1 at
    # (0.966-1.061, 0.259+1.061) = (-0.095, 1.319): 1.323 m at 94.1° (sector 3)
    p6 = positions[0, 6]
    d1 = (positions[0, 1] - p6).norm().item()
    expected6 = [3.0] * 12
    expected6[4], expected6[3] = 1.5, d1
    assert grid[0, 6].tolist() == pytest.approx(expected6, abs=1e-5)


def test_apg_sector_count_and_radius_are_parameters():
    positions = th.tensor([[[0.0, 0.0], polar(1.0, 100.0), polar(1.8, 260.0)]])
    grid = angular_pedestrian_grid(positions, th.ones(1, 3, dtype=th.bool), num_sectors=4, r_max=1.5)
    assert grid[0, 0].tolist() == pytest.approx([1.5, 1.0, 1.5, 1.5], abs=1e-6)  # the 1.8 m one is clipped


def test_apg_batched_over_leading_dims_and_coincident():
    positions = th.zeros(2, 3, 4, 2)  # everybody on the same spot: distance 0, sector 0
    grid = angular_pedestrian_grid(positions, th.ones(2, 3, 4, dtype=th.bool))
    assert grid.shape == (2, 3, 4, 12)
    assert (grid[..., 0] == 0).all() and (grid[..., 1:] == 3.0).all()


def test_apg_wrong_shapes_raise():
    with pytest.raises(ValueError, match="positions"):
        angular_pedestrian_grid(th.zeros(2, 4, 3), th.ones(2, 4, dtype=th.bool))
    with pytest.raises(ValueError, match="present"):
        angular_pedestrian_grid(th.zeros(2, 4, 2), th.ones(2, 5, dtype=th.bool))


@pytest.mark.parametrize("num_sectors", [1, 2, 3, 5, 12])
def test_sectors_are_those_of_the_angle(num_sectors):
    rng = np.random.default_rng(num_sectors)
    x, y = rng.normal(size=(2, 20000)) * rng.choice([1e-6, 1.0, 1e4], size=(2, 20000))
    expected = np.floor(np.mod(np.arctan2(y, x), 2 * np.pi) / (2 * np.pi / num_sectors)).astype(int) % num_sectors
    np.testing.assert_array_equal(sector_of(th.as_tensor(x), th.as_tensor(y), num_sectors).numpy(), expected)


@pytest.mark.parametrize("num_sectors", [3, 4, 12])
def test_sectors_are_decided_exactly_at_their_edges(num_sectors):
    """1e-12 rad either side of every edge (a float32 atan2 rounds both onto it), and on the axes and at (0, 0)."""
    edges = 2 * np.pi * np.arange(num_sectors) / num_sectors
    for offset, shift in ((1e-12, 0), (-1e-12, -1)):
        radius = np.array([1e-3, 1.0, 7.3])[:, None]
        x, y = radius * np.cos(edges + offset), radius * np.sin(edges + offset)
        expected = np.broadcast_to((np.arange(num_sectors) + shift) % num_sectors, x.shape)
        np.testing.assert_array_equal(sector_of(th.as_tensor(x), th.as_tensor(y), num_sectors).numpy(), expected)
    axes = th.tensor([[2.0, 0.0], [0.0, 2.0], [-2.0, 0.0], [0.0, -2.0], [0.0, 0.0], [-2.0, -0.0]], dtype=th.float64)
    expected = [k * num_sectors // 4 for k in range(4)] + [0, num_sectors // 2]  # -0.0: at π, as atan2(0, -2)
    assert sector_of(axes[:, 0], axes[:, 1], num_sectors).tolist() == expected


def test_apg_axis_turns_the_sectors():
    """Sector 0 starts at ``axis``: positions and axis turned together by a quarter-turn (exact in floats) give the
    same grid, bit for bit; a zero axis is the x-axis."""
    g = th.Generator().manual_seed(4)
    positions, present = 3 * th.randn(5, 2, 6, 2, generator=g), th.rand(5, 2, 6, generator=g) > 0.2
    axis = th.randn(5, 2, 2, generator=g)

    def turn(v):
        return th.stack((-v[..., 1], v[..., 0]), dim=-1)

    grid = angular_pedestrian_grid(positions, present, axis=axis)
    assert th.equal(angular_pedestrian_grid(turn(positions), present, axis=turn(axis)), grid)
    assert th.equal(angular_pedestrian_grid(positions, present, axis=th.zeros(5, 2, 2)),
                    angular_pedestrian_grid(positions, present))
    with pytest.raises(ValueError, match="axis"):
        angular_pedestrian_grid(positions, present, axis=th.zeros(5, 2))


def test_apg_in_extractor_is_in_goal_frame(space):
    """Rotating and translating the whole world leaves every encoder's output unchanged."""
    obs = random_obs(4, 5, seed=3)
    angle, shift = 0.7, th.tensor([1.5, -2.0])
    c, s = math.cos(angle), math.sin(angle)
    rot = th.tensor([[c, -s], [s, c]])
    moved = {k: v.clone() for k, v in obs.items()}
    r = moved["robot"]
    r[:, Robot.POS] = r[:, Robot.POS] @ rot.T + shift
    r[:, Robot.GOAL] = r[:, Robot.GOAL] @ rot.T + shift
    r[:, Robot.VEL] = r[:, Robot.VEL] @ rot.T
    r[:, Robot.HEADING] = th.remainder(r[:, Robot.HEADING] + angle + math.pi, 2 * math.pi) - math.pi
    h = humans_view(moved)
    present = moved["humans_mask"][:, None, :, None] > 0.5
    h[..., Human.POS] = th.where(present, h[..., Human.POS] @ rot.T + shift, 0.0)
    h[..., Human.VEL] = h[..., Human.VEL] @ rot.T
    for name in EXTRACTORS:
        model = make(name, space)
        with th.no_grad():
            assert th.allclose(model(obs), model(moved), atol=2e-4), name


# ----------------------------------------------------------------------------- other interaction terms


def test_local_map_counts_and_mean_velocity():
    # pedestrian 0 at the origin walking +x; others at (0.5, 0.5) [cell col 2,row 2] x2 and (-1.5, -1.5) [col 0,row 0]
    positions = th.tensor([[[0.0, 0.0], [0.5, 0.5], [0.6, 0.4], [-1.5, -1.5], [3.0, 0.0]]])
    velocities = th.tensor([[[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [1.0, 1.0]]])
    present = th.ones(1, 5, dtype=th.bool)
    om = local_occupancy_map(positions, velocities, present).view(1, 5, 16, 3)
    cells = om[0, 0]
    assert cells[2 * 4 + 2].tolist() == pytest.approx([2.0, 0.5, 0.5])
    assert cells[0].tolist() == pytest.approx([1.0, 0.0, 0.0])
    assert cells.sum().item() == pytest.approx(4.0)  # the one at 3 m is outside the 4 m x 4 m map
    present[0, 1] = False
    cells = local_occupancy_map(positions, velocities, present).view(1, 5, 16, 3)[0, 0]
    assert cells[2 * 4 + 2].tolist() == pytest.approx([1.0, 0.0, 1.0])


def test_social_forces_direction_and_padding():
    positions = th.tensor([[[1.0, 0.0], [2.0, 0.0], [1.5, 0.0]]])
    radii = th.full((1, 3), 0.3)
    present = th.tensor([[True, True, False]])
    on_human, on_robot = social_forces(positions, radii, present, th.tensor([0.3]))
    magnitude = 2.1 * math.exp((0.6 - 1.0) / 0.3)
    assert on_human[0, 0].tolist() == pytest.approx([-magnitude, 0.0], rel=1e-5)  # pushed away from pedestrian 1
    assert on_robot[0, 0].tolist() == pytest.approx([-magnitude, 0.0], rel=1e-5)  # robot at the origin pushed -x
    assert on_robot[0, 2].tolist() == [0.0, 0.0]


# ----------------------------------------------------------------------------- every encoder


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_masked_slots_do_not_matter(name, space):
    model = make(name, space)
    obs = random_obs(6, [0, 1, 3, 5, 7, 10], seed=1)
    with th.no_grad():
        ref = model(obs)
    garbage = {k: v.clone() for k, v in obs.items()}
    padded = (garbage["humans_mask"] <= 0.5)[:, None, :, None].expand(-1, T, -1, HUMAN_DIM)
    h = humans_view(garbage)
    noise = 50 * th.randn(h.shape, generator=th.Generator().manual_seed(7))
    noise[..., 0] = th.nan
    h[padded] = noise[padded]
    garbage["humans_mask"][garbage["humans_mask"] <= 0.5] = 0.4  # not a present human: mask > 0.5 only
    with th.no_grad():
        out = model(garbage)
    assert th.isfinite(out).all()
    assert th.allclose(out, ref, atol=1e-5)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_slot_order_does_not_matter(name, space):
    model = make(name, space)
    obs = random_obs(5, [1, 3, 6, 9, 10], seed=2)
    perm = th.randperm(N, generator=th.Generator().manual_seed(3))
    permuted = {
        "robot": obs["robot"],
        "humans": humans_view(obs)[:, :, perm].reshape(5, -1),
        "humans_mask": obs["humans_mask"][:, perm],
    }
    with th.no_grad():
        assert th.allclose(model(obs), model(permuted), atol=1e-5)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_rows_are_independent_of_the_batch(name, space):
    """Compacting slots to the batch's largest count must not couple the rows."""
    model = make(name, space)
    obs = random_obs(4, [0, 2, 10, 5], seed=4)
    with th.no_grad():
        batched = model(obs)
        for b in range(4):
            alone = model({k: v[b : b + 1] for k, v in obs.items()})
            assert th.allclose(batched[b : b + 1], alone, atol=1e-5)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_nobody_present_is_finite(name, space):
    model = make(name, space)
    obs = random_obs(3, 0, seed=5)
    out = model(obs)
    assert out.shape == (3, model.features_dim)
    assert th.isfinite(out).all()
    if out.requires_grad:  # without pedestrians the features may not depend on any parameter
        out.sum().backward()
        assert all(p.grad is None or th.isfinite(p.grad).all() for p in model.parameters())
    mixed = random_obs(3, [0, 4, 0], seed=5)  # no NaN gradient from the empty rows of a mixed batch
    model(mixed).sum().backward()
    assert all(p.grad is None or th.isfinite(p.grad).all() for p in model.parameters())


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_gradients_reach_every_parameter(name, space):
    model = make(name, space).train()
    obs = random_obs(16, [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 6, 6, 6, 3, 2, 10], seed=6, spread=2.5)
    out = model(obs)
    (out**2).sum().backward()
    for pname, param in model.named_parameters():
        assert param.grad is not None, pname
        assert th.isfinite(param.grad).all(), pname
        assert param.grad.abs().sum() > 0, pname


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_extreme_valid_inputs_are_finite(name, space):
    model = make(name, space)
    hi_r = th.as_tensor(space["robot"].high)
    hi_h = th.as_tensor(space["humans"].high).view(T, N, HUMAN_DIM)
    obs = random_obs(4, 10, seed=8)
    robot, h = obs["robot"], humans_view(obs)
    # row 0: every human exactly on the robot (and on each other)
    h[0, :, :, Human.POS] = robot[0, Robot.POS]
    # row 1: the robot on its goal, humans at the far corner of the box, at top speed
    robot[1, Robot.GOAL] = robot[1, Robot.POS]
    h[1, :, :, Human.POS] = hi_h[..., Human.POS]
    h[1, :, :, Human.VEL] = hi_h[..., Human.VEL]
    # row 2: robot and goal at opposite corners of the box, humans at the largest radius
    robot[2, Robot.POS] = -hi_r[Robot.POS]
    robot[2, Robot.GOAL] = hi_r[Robot.GOAL]
    robot[2, Robot.VEL] = hi_r[Robot.VEL]
    h[2, :, :, Human.RADIUS] = hi_h[..., Human.RADIUS]
    # row 3: zero radii and zero velocities
    h[3, :, :, Human.RADIUS] = 0.0
    h[3, :, :, Human.VEL] = 0.0
    out = model(obs)
    assert th.isfinite(out).all()
    out.sum().backward()
    assert all(th.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_inference_path_equals_training_path(name, space):
    """Without gradients the MLPs take the fused oneDNN kernels; the numbers must not change."""
    model = make(name, space)
    obs = random_obs(8, [0, 1, 2, 4, 6, 8, 10, 6], seed=10)
    with_grad = model(obs)
    previous = layers._ONEDNN["enabled"]  # the CPU's default
    set_onednn_inference(True)
    try:
        with th.no_grad():
            without = model(obs)
        assert th.allclose(with_grad, without, atol=1e-5)
        set_onednn_inference(False)
        with th.no_grad():
            assert th.allclose(model(obs), without, atol=1e-5)
    finally:
        set_onednn_inference(previous)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_onednn_gradients_equal_plain_linear_gradients(name, space):
    """With gradients the MLPs run oneDNN's forward and backward kernels; values and gradients must match nn.Linear's."""
    model = make(name, space)
    obs = random_obs(8, [0, 1, 2, 4, 6, 8, 10, 6], seed=11)

    def run(onednn: bool) -> list[th.Tensor]:
        previous = layers._ONEDNN["training"]  # the CPU's default
        set_onednn_training(onednn)
        try:
            model.zero_grad()
            out = model(obs)
            (out * th.linspace(-1.0, 1.0, out.shape[1])).sum().backward()
        finally:
            set_onednn_training(previous)
        return [out.detach()] + [p.grad.clone() for p in model.parameters() if p.grad is not None]

    fast, plain = run(True), run(False)
    assert len(fast) == len(plain) > 1
    for a, b in zip(fast, plain, strict=True):
        assert th.allclose(a, b, rtol=1e-4, atol=1e-5)


def test_onednn_linear_gradient_against_finite_differences():
    """The custom backward (ReLU mask, input, weight and bias gradients) against central finite differences."""
    from sb3_crowdnav.nn.layers import linear

    gen = th.Generator().manual_seed(0)
    layer = th.nn.Linear(4, 3)
    with th.no_grad():  # fixed weights: the test must not depend on the global RNG (which inputs sit near a ReLU kink)
        layer.weight.copy_(th.randn(3, 4, generator=gen))
        layer.bias.copy_(th.randn(3, generator=gen))
    x = th.randn(2, 5, 4, generator=gen, requires_grad=True)
    weights = th.randn(2, 5, 3, generator=gen)

    def loss() -> th.Tensor:
        return (linear(x, layer, relu=True) * weights).sum()

    loss().backward()
    assert x.grad is not None and layer.weight.grad is not None and layer.bias.grad is not None
    eps = 1e-2
    for tensor, grad in ((x, x.grad), (layer.weight, layer.weight.grad), (layer.bias, layer.bias.grad)):
        flat, gflat = tensor.data.view(-1), grad.view(-1)
        for i in range(0, flat.numel(), 3):
            old = flat[i].item()
            with th.no_grad():
                flat[i] = old + eps
                up = loss().item()
                flat[i] = old - eps
                down = loss().item()
                flat[i] = old
            assert (up - down) / (2 * eps) == pytest.approx(gflat[i].item(), abs=2e-3)
    # its output may be modified in place (the APG encoder adds to it)
    y = linear(x, layer)
    y.add_(1.0).sum().backward()


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_wrong_tensor_shapes_raise(name, space):
    model = make(name, space)
    obs = random_obs(2, 3)
    bad = dict(obs, humans=obs["humans"][:, :-5])
    with pytest.raises(ValueError, match=r"humans \(2, 245\)"):
        model(bad)
    with pytest.raises(ValueError, match="humans_mask"):
        model(dict(obs, humans_mask=obs["humans_mask"][:, :-1]))


# ----------------------------------------------------------------------------- observation space and sizes


def test_space_inference_and_validation(space):
    assert parse_observation_space(space) == (T, N)
    small = gym.spaces.Dict({
        "robot": space["robot"],
        "humans": gym.spaces.Box(-1.0, 1.0, (3 * 4 * HUMAN_DIM,), np.float32),
        "humans_mask": gym.spaces.Box(0.0, 1.0, (4,), np.float32),
    })
    model = ApgExtractor(small)
    assert (model.history_length, model.max_humans) == (3, 4)
    obs = {
        "robot": th.zeros(2, ROBOT_DIM),
        "humans": th.zeros(2, 3 * 4 * HUMAN_DIM),
        "humans_mask": th.tensor([[1.0, 0, 0, 1], [0, 0, 0, 0]]),
    }
    assert model(obs).shape == (2, 57)
    with pytest.raises(TypeError, match="Dict"):
        ApgExtractor(space["robot"])
    with pytest.raises(ValueError, match="lacks key"):
        ApgExtractor(gym.spaces.Dict({"robot": space["robot"], "humans": space["humans"]}))
    bad = gym.spaces.Dict({
        "robot": space["robot"],
        "humans": gym.spaces.Box(-1.0, 1.0, (7,), np.float32),
        "humans_mask": space["humans_mask"],
    })
    with pytest.raises(ValueError, match="T \\* max_humans"):
        ApgExtractor(bad)


def test_sizes_are_keyword_arguments(space):
    model = ApgExtractor(
        space, embedding_arch=(32, 16), interaction_arch=(24, 8), attention_arch=(12, 1), lstm_hidden_size=10,
        num_sectors=8, r_max=2.0,
    )
    assert model.features_dim == 7 + 10
    assert model(random_obs(3, 4)).shape == (3, 17)
    with pytest.raises(ValueError, match="attention_arch must end with 1"):
        ApgExtractor(space, attention_arch=(100, 100))
    with pytest.raises(ValueError, match=r"embedding_arch\[0\] must be >= 1"):
        ApgExtractor(space, embedding_arch=(0,))
    with pytest.raises(TypeError, match=r"embedding_arch\[1\] must be an int"):
        ApgExtractor(space, embedding_arch=(16, 8.0))


def test_features_dims(space):
    dims = {name: cls(space).features_dim for name, cls in EXTRACTORS.items()}
    assert dims == {"apg": 57, "cadrl": 107, "sf": 57, "lm": 57, "lstm_rl": 57, "sarl": 57}


def test_apg_default_sizes_follow_table_2(space):
    model = ApgExtractor(space)
    assert [(m.in_features, m.out_features) for m in model.psi_e.layers] == [(7 + 12, 150), (150, 100)]
    assert model.psi_h_out.out_features == 50 and model.psi_alpha_step.in_features == 100
    assert model.psi_alpha_step.out_features == 100
    assert model.lstm.hidden_size == 50


def test_apg_rewritings_equal_the_plain_equations(space):
    """The split ψ_alpha first layer and the late ψ_h output layer compute Eq. 4-8 exactly."""
    model = make("apg", space)
    obs = random_obs(3, 4, seed=9)
    _, human_feats, valid, lengths = model._robot_centric(obs)
    grid = angular_pedestrian_grid(human_feats[..., HumanFeat.POS], valid[:, None].expand(-1, T, -1))
    s = th.cat((human_feats, grid), -1).transpose(1, 2)  # (B, L, T, F), steps on dim 2 here
    with th.no_grad():
        e = model.psi_e(s)
        h = model.psi_h_out(model.psi_h_hidden(e))
        e_a = e.mean(dim=2, keepdim=True).expand_as(e)
        w1 = th.cat((model.psi_alpha_step.weight, model.psi_alpha_mean.weight), dim=1)
        pre = th.nn.functional.linear(th.cat((e, e_a), -1), w1, model.psi_alpha_step.bias)
        alpha = model.psi_alpha_rest(th.relu(pre))
        e_o = (th.softmax(alpha, dim=2) * h).sum(dim=2)
        _, (h_n, _) = model.lstm(e_o[:, : int(lengths.max())])
        out = model(obs)
    assert lengths.tolist() == [4, 4, 4]
    assert th.allclose(out[:, 7:], h_n[0], atol=1e-5)


def test_the_onednn_kernels_are_the_default_only_on_avx512():
    # where oneDNN and MKL both run AVX2 kernels, nn.Linear is the faster on a lookahead's batches and gradient steps
    avx512 = th.backends.cpu.get_cpu_capability().startswith("AVX512")
    assert layers._ONEDNN["enabled"] == layers._ONEDNN["training"] == avx512
