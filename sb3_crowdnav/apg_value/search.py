"""The lookahead's search: Q of every action of a batch of observations, from V after one step or after several.

One step (the paper): ``Q(s, a) = R(s, a) + γ^(Δt·v_pref)·V(s')`` for every action, V cut at the world's value ceiling.
With ``planning_depth`` d > 1 the state each action reaches is propagated again, and ``V(s')`` is replaced by the best
Q of the (d - 1)-step search from it. Two ways to choose what is searched deeper:

* every successor (``planning_width`` None): each distinct state once; the cost grows as the distinct successors to
  the power d (about 11 a step under the warehouse robot's limits, 80 on the open floor);
* the best ``planning_width`` k actions of each step (a beam): the one-step Q of every action ranks them
  (:func:`best_actions`: ties to the lower action index, the rule of ONNX's ``TopK``, so the exported graph expands
  the same ones), those k are searched deeper and their Q replaced by the deeper one, the others keep their one-step
  Q, and the decision is the argmax over all. A d-step search then costs about A + k·A + ... + k^(d-1)·A states
  instead of A^d.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_crowdnav.apg_value.propagation import Propagated
from sb3_crowdnav.sim.observation import OBSTACLE_KEYS, WAYPOINT_KEY, Robot
from sb3_crowdnav.sim.validation import check_int

STATIC_KEYS = (*OBSTACLE_KEYS, WAYPOINT_KEY)  # the warehouse's, propagated when the observation has them


def check_cap_values(cap_values: bool | None) -> bool | None:
    """``cap_values`` None, True or False (:class:`ValueLookaheadPolicy`); back as given."""
    if cap_values is not None and not isinstance(cap_values, bool):
        raise TypeError(f"cap_values must be None (the world's rule), True or False, got {cap_values!r}")
    return cap_values


def check_planning(planning_depth: int, planning_width: int | None) -> tuple[int, int | None]:
    """``planning_depth`` an int >= 1, ``planning_width`` None or an int >= 1 and only with a depth > 1; both back."""
    check_int("planning_depth", planning_depth, 1)
    if planning_width is not None:
        check_int("planning_width", planning_width, 1)
        if planning_depth == 1:
            raise ValueError(f"planning_width={planning_width!r} needs planning_depth > 1 (a one-step lookahead "
                             f"searches nothing deeper); got planning_depth=1")
    return int(planning_depth), None if planning_width is None else int(planning_width)


def best_actions(q: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` actions of largest Q of each row of ``q`` (B, A), best first, equal values in action order:
    (B, min(width, A)) indices."""
    return np.argsort(-q, axis=1, kind="stable")[:, :width]


def search(policy: Any, observation: dict[str, np.ndarray], net: nn.Module,
           depth: int) -> tuple[np.ndarray, Propagated]:
    """Q of every action of B numpy observations, (B, A), searched ``depth`` steps as the module docstring says
    (``policy.planning_width`` chooses how), and the first step's propagation.

    :param policy: the :class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy` (its propagation, successors, value
        ceiling and ``planning_width``)
    :param net: V (the policy's ``value_net`` or a network of the same architecture)
    """
    static = {k: observation[k] for k in STATIC_KEYS if k in observation}
    prop = policy.propagation(observation["robot"], observation["humans"], observation["humans_mask"], static)
    b, n_actions = prop.reward.shape
    width = policy.planning_width
    if depth > 1 and (width is None or width >= n_actions):  # every successor, each distinct one once
        states, inverse = policy.successors(prop)
        v = search(policy, states, net, depth - 1)[0].max(axis=1)
        v = (v if inverse is None else v[inverse]).reshape(b, n_actions)
        return prop.reward + prop.discount[:, None] * np.where(prop.terminal, 0.0, v), prop
    if depth > 1:  # the one-step Q of every action ranks them; the best `width` are searched deeper
        states, inverse = policy.successors(prop)
        tensors = {k: th.as_tensor(v, dtype=th.float32, device=policy.device) for k, v in states.items()}
    else:
        tensors, inverse = policy.lookahead_inputs(prop)
    with th.inference_mode():  # a little cheaper than no_grad; the values leave as numpy
        v = net(tensors).reshape(-1).cpu().numpy()
    v = (v if inverse is None else v[inverse]).reshape(b, n_actions)
    # V at the last step is cut at the value ceiling (a deeper search's Q holds it already)
    ceiling = policy.value_ceiling(np.asarray(observation["robot"], dtype=np.float64)[:, Robot.V_PREF])
    if ceiling is not None:
        v = np.minimum(v, ceiling[:, None])
    q = prop.reward + prop.discount[:, None] * np.where(prop.terminal, 0.0, v)
    if depth == 1:
        return q, prop
    top = best_actions(q, width)  # (B, k)
    rows = (np.arange(b)[:, None] * n_actions + top).reshape(-1)  # their (observation, action) pairs
    rows = rows if inverse is None else inverse[rows]
    kept, where = np.unique(rows, return_inverse=True)  # each distinct state once
    deeper = search(policy, {key: value[kept] for key, value in states.items()}, net, depth - 1)[0].max(axis=1)
    deeper = deeper[where.reshape(-1)].reshape(top.shape)
    batch = np.arange(b)[:, None]
    q[batch, top] = prop.reward[batch, top] + prop.discount[:, None] * np.where(prop.terminal[batch, top], 0.0,
                                                                                   deeper)
    return q, prop
