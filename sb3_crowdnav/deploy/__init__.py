"""Deploying a trained model: its whole greedy decision as one ONNX graph, run by ONNX Runtime.

:func:`export_onnx` writes the graph (for ``APGValue`` the propagation over every action, the reward model, the
warehouse's obstacle checks, the value network(s) and the argmax; for SB3's DQN and PPO the Q network or the actor,
for sb3-contrib's QRDQN the mean of the quantiles, for MaskablePPO the actor with an ``action_masks`` input)
with the world contract as metadata (:class:`GraphMetadata`); :class:`OnnxPolicy` runs it behind SB3's ``predict``;
:class:`ObservationBuilder` turns a robot's tracker output, odometry and goal into the observation it takes.
The export and the runtime need the optional dependencies of the ``deploy`` extra (``pip install
"sb3-crowdnav[deploy]"``: onnx, onnxscript and onnxruntime), imported when first used; the builder needs none. See the
docs, "Deploying on a robot".
"""

from sb3_crowdnav.deploy.builder import (
    BuilderError,
    FrameMismatch,
    MissingInput,
    NonFiniteInput,
    ObservationBuilder,
    TimeOrderError,
    UnknownId,
)
from sb3_crowdnav.deploy.export import export_onnx
from sb3_crowdnav.deploy.metadata import OPSET, GraphMetadata
from sb3_crowdnav.deploy.runtime import OnnxPolicy
from sb3_crowdnav.deploy.tracking import BuilderSettings

__all__ = [
    "OPSET",
    "BuilderError",
    "BuilderSettings",
    "FrameMismatch",
    "GraphMetadata",
    "MissingInput",
    "NonFiniteInput",
    "ObservationBuilder",
    "OnnxPolicy",
    "TimeOrderError",
    "UnknownId",
    "export_onnx",
]
