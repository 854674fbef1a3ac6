"""Combining trained value models: weight averaging over one run's checkpoints, value ensembles across runs.

Weight averaging (stochastic weight averaging, Izmailov et al., 2018):

A value run's checkpoints near its best validation differ by the noise of the last few hundred episodes' updates;
the mean of their weights (with ``torch.optim.swa_utils.AveragedModel``) is one network of the same architecture,
usually flatter and steadier than any one of them. Example::

    from sb3_crowdnav.training import average_checkpoints

    model = average_checkpoints([f"runs/apg_warehouse/checkpoint_{n}.zip" for n in range(6000, 8001, 500)])
    model.save("runs/apg_warehouse/average.zip")

The first checkpoint gives everything but V's weights (settings, spaces, episode and step counts); V_target is set
to the average too, and the optimiser state is dropped (a continued run would start its own).

Value ensembles (:func:`ensemble_models`): models of *different* runs have unrelated weights (their mean is no
network), but the mean of their values is a value: one model whose V is a
:class:`~sb3_crowdnav.apg_value.policies.ValueEnsemble` of theirs. Each decision costs one forward pass per member::

    from sb3_crowdnav.training import ensemble_models

    model = ensemble_models(["runs/apg_warehouse/checkpoint_7000.zip", "runs/apg_warehouse_b/checkpoint_6500.zip"])
    model.save("runs/apg_warehouse_ensemble.zip")  # loads like any APGValue model
"""

from __future__ import annotations

import collections
from collections.abc import Sequence
from pathlib import Path

import torch as th
from torch.optim.swa_utils import AveragedModel

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.policies import LOOKAHEAD_SETTINGS, ValueEnsemble
from sb3_crowdnav.sim.world import compare_worlds


def average_checkpoints(paths: Sequence[str | Path], **load_kwargs) -> APGValue:
    """The model of ``paths[0]`` with V's weights replaced by their mean over all ``paths``.

    :param paths: two or more saved :class:`~sb3_crowdnav.apg_value.APGValue` models of the same architecture
        (typically checkpoints of one run)
    :param load_kwargs: passed to :meth:`APGValue.load` for every path (e.g. ``env``)
    :raises ValueError: fewer than two paths, or checkpoints whose V differs in parameter names or shapes, or whose
        observation spaces or worlds differ
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise ValueError(f"paths: average_checkpoints needs at least two checkpoints, got {len(paths)}")
    base = APGValue.load(paths[0], **load_kwargs)
    average = AveragedModel(base.policy.value_net)
    average.update_parameters(base.policy.value_net)
    shapes = {name: tuple(t.shape) for name, t in base.policy.value_net.state_dict().items()}
    for path in paths[1:]:
        model = APGValue.load(path, **load_kwargs)
        other = {name: tuple(t.shape) for name, t in model.policy.value_net.state_dict().items()}
        if other != shapes:
            raise ValueError(f"paths: {path} has another value network than {paths[0]} (parameter names or shapes "
                             "differ)")
        if model.observation_space != base.observation_space:
            raise ValueError(f"paths: {path} observes another space than {paths[0]}")
        _check_same_world(path, model, paths[0], base)
        average.update_parameters(model.policy.value_net)
    with th.no_grad():
        base.policy.value_net.load_state_dict(average.module.state_dict())
        base.policy.value_net_target.load_state_dict(average.module.state_dict())
    base.policy.optimizer.state = collections.defaultdict(dict)
    return base


# the settings every member of an ensemble must share beside the world: the discount and the network's architecture
_SHARED_POLICY_SETTINGS = ("gamma", "net_arch", "activation_fn", "features_extractor_class",
                           "features_extractor_kwargs")


def _check_same_world(path: Path, model: APGValue, first: Path, base: APGValue) -> None:
    """``ValueError`` listing the fields in which ``model``'s world differs from ``base``'s (all of them matter: a
    combined V is only a value of the world every member learned)."""
    mismatch = compare_worlds(model.policy.world, base.policy.world, against=str(first))
    if mismatch:
        raise ValueError(f"paths: {path}: {mismatch}")


def ensemble_models(paths: Sequence[str | Path], **load_kwargs) -> APGValue:
    """One model whose V is the mean of the value networks of all ``paths`` (a value ensemble).

    The result is the model of ``paths[0]`` (settings, spaces, counters, pedestrian model) with
    ``policy_kwargs["ensemble_size"]`` the total number of members (a member that is an ensemble itself contributes
    its members); V_target holds the same networks and the optimiser state is empty. It saves and loads like any
    :class:`~sb3_crowdnav.apg_value.APGValue` model.

    :param paths: two or more saved ``APGValue`` models (typically of independent runs) of the same world and
        architecture
    :param load_kwargs: passed to :meth:`APGValue.load` for every path (e.g. ``env``)
    :raises ValueError: fewer than two paths, or models whose observation spaces, lookahead settings (time step,
        discount, kinematics, action fan, reward, obstacle settings) or network architecture differ
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise ValueError(f"paths: ensemble_models needs at least two models, got {len(paths)}")
    models = [APGValue.load(path, **load_kwargs) for path in paths]
    base = models[0]
    members: list[th.nn.Module] = []
    for path, model in zip(paths, models, strict=True):
        if model.observation_space != base.observation_space:
            raise ValueError(f"paths: {path} observes another space than {paths[0]}")
        _check_same_world(path, model, paths[0], base)
        for name in _SHARED_POLICY_SETTINGS:
            if getattr(model.policy, name) != getattr(base.policy, name):
                raise ValueError(f"paths: {path} has {name} = {getattr(model.policy, name)!r}, {paths[0]} has "
                                 f"{getattr(base.policy, name)!r}; an ensemble's members must share it")
        net = model.policy.value_net
        members.extend(net.members if isinstance(net, ValueEnsemble) else [net])
    base.policy_kwargs["ensemble_size"] = len(members)
    policy = base.policy_class(base.observation_space, base.action_space, base.lr_schedule, **base.policy_kwargs)
    for name in LOOKAHEAD_SETTINGS:  # how the first model acts: set_pedestrian_model, set_stopping_check, ...
        getattr(policy, f"set_{name}")(getattr(base.policy, name))
    with th.no_grad():
        for target in (policy.value_net, policy.value_net_target):
            for slot, member in zip(target.members, members, strict=True):
                slot.load_state_dict(member.state_dict())
    base.policy = policy.to(base.device)
    base.policy.set_training_mode(False)
    return base
