"""Deploying a trained model: its whole greedy decision as one ONNX graph, run by ONNX Runtime.

:func:`export_onnx` writes the graph (for ``APGValue`` the propagation over every action, the reward model, the
warehouse's obstacle checks, the value network(s) and the argmax; for SB3's DQN and PPO the Q network or the actor)
with the world contract as metadata (:class:`GraphMetadata`); :class:`OnnxPolicy` runs it behind SB3's ``predict``.
Both need the optional dependencies of the ``deploy`` extra (``pip install "sb3-crowdnav[deploy]"``: onnx,
onnxscript and onnxruntime), imported when first used. See the docs, "Deploying on a robot".
"""

from sb3_crowdnav.deploy.export import export_onnx
from sb3_crowdnav.deploy.metadata import OPSET, GraphMetadata
from sb3_crowdnav.deploy.runtime import OnnxPolicy

__all__ = ["OPSET", "GraphMetadata", "OnnxPolicy", "export_onnx"]
