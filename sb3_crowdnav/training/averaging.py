"""Weight averaging over the checkpoints of one run (stochastic weight averaging, Izmailov et al., 2018).

A value run's checkpoints near its best validation differ by the noise of the last few hundred episodes' updates;
the mean of their weights (with ``torch.optim.swa_utils.AveragedModel``) is one network of the same architecture,
usually flatter and steadier than any one of them. Example::

    from sb3_crowdnav.training import average_checkpoints

    model = average_checkpoints([f"runs/apg_warehouse/checkpoint_{n}.zip" for n in range(6000, 8001, 500)])
    model.save("runs/apg_warehouse/average.zip")

The first checkpoint gives everything but V's weights (settings, spaces, episode and step counts); V_target is set
to the average too, and the optimiser state is dropped (a continued run would start its own).
"""

from __future__ import annotations

import collections
from collections.abc import Sequence
from pathlib import Path

import torch as th
from torch.optim.swa_utils import AveragedModel

from sb3_crowdnav.apg_value import APGValue


def average_checkpoints(paths: Sequence[str | Path], **load_kwargs) -> APGValue:
    """The model of ``paths[0]`` with V's weights replaced by their mean over all ``paths``.

    :param paths: two or more saved :class:`~sb3_crowdnav.apg_value.APGValue` models of the same architecture
        (typically checkpoints of one run)
    :param load_kwargs: passed to :meth:`APGValue.load` for every path (e.g. ``env``)
    :raises ValueError: fewer than two paths, or checkpoints whose V differs in parameter names or shapes, or whose
        observation spaces differ
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
        average.update_parameters(model.policy.value_net)
    with th.no_grad():
        base.policy.value_net.load_state_dict(average.module.state_dict())
        base.policy.value_net_target.load_state_dict(average.module.state_dict())
    base.policy.optimizer.state = collections.defaultdict(dict)
    return base
