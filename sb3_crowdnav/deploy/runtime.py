"""``OnnxPolicy``: an exported decision graph run by ONNX Runtime behind SB3's ``predict``.

The evaluation harness, ``sb3-crowdnav evaluate --policy FILE.onnx`` and a robot's own loop run it like any policy.
It reads the graph's contract (:class:`~sb3_crowdnav.deploy.metadata.GraphMetadata`) when it is built, checks every
observation's keys and shapes against the embedded layout, and, given an env, the env's observation space and world
against the embedded ones. An ``.onnx`` file is data: ONNX Runtime runs the graph's standard operators (no custom
operator library is registered), and the metadata is read as JSON only.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sb3_crowdnav.deploy.metadata import MASK_INPUT, OUTPUT_NAMES, GraphMetadata, require
from sb3_crowdnav.serialization import world_of
from sb3_crowdnav.sim.observation import ObservationSchema, Robot
from sb3_crowdnav.sim.validation import check_choice, check_int
from sb3_crowdnav.sim.world import MOTION_FIELDS, PREDICTION_FIELDS, compare_worlds, env_keywords

# ONNX Runtime's graph optimisation levels by their short names
OPTIMIZATION_LEVELS = {"all": "ORT_ENABLE_ALL", "extended": "ORT_ENABLE_EXTENDED", "basic": "ORT_ENABLE_BASIC",
                       "disabled": "ORT_DISABLE_ALL"}


class OnnxPolicy:
    """A graph written by :func:`~sb3_crowdnav.deploy.export_onnx`, run by ONNX Runtime on the CPU.

    :param path: the ``.onnx`` file
    :param env: the env it acts in (a crowd env or a VecEnv of them), checked now: its observation shapes must be
        the graph's, and its world the one the model was trained in (for a lookahead also the waypoint rule it
        predicts with); a mismatch is a ``ValueError`` naming the fields
    :param allow_env_mismatch: act in an env of another world anyway (its shapes are still checked)
    :param num_threads: ONNX Runtime's intra-op threads (default 1: on a robot the other cores stay free, and these
        small networks gain little from more)
    :param optimization: ONNX Runtime's graph optimisation level, ``"all"`` (default), ``"extended"``, ``"basic"`` or
        ``"disabled"``
    """

    def __init__(self, path: str | Path, env: Any = None, *, allow_env_mismatch: bool = False, num_threads: int = 1,
                 optimization: str = "all") -> None:
        check_int("num_threads", num_threads, 1)
        check_choice("optimization", optimization, tuple(OPTIMIZATION_LEVELS))
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"no ONNX graph at {str(path)!r}")
        ort = require("onnxruntime", "OnnxPolicy")
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(num_threads)
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = getattr(ort.GraphOptimizationLevel, OPTIMIZATION_LEVELS[optimization])
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # ONNX Runtime's own error types: a file it cannot read or run
            raise ValueError(f"{self.path} is not an ONNX graph ONNX Runtime can run: {exc}") from None
        self.metadata = GraphMetadata.from_props(self.session.get_modelmeta().custom_metadata_map)
        self._check_graph()
        self._fastest = self.metadata.fastest_fraction  # read once: the braking check runs on every call
        if env is not None:
            self.check_env(env, allow_env_mismatch)

    def _check_graph(self) -> None:
        """The graph's inputs and outputs are those its metadata describes."""
        meta = self.metadata
        inputs = {value.name: (value.shape, value.type) for value in self.session.get_inputs()}
        outputs = [value.name for value in self.session.get_outputs()]
        expected = {key: ([shape[0]], "tensor(float)") for key, shape in meta.schema.shapes.items()}
        if MASK_INPUT in meta.inputs:
            expected[MASK_INPUT] = ([meta.world.n_actions], "tensor(bool)")
        got = {name: ([d for d in shape[1:]], kind) for name, (shape, kind) in inputs.items() if len(shape) == 2}
        if list(inputs) != list(meta.inputs) or got != expected or outputs != list(OUTPUT_NAMES):
            raise ValueError(f"{self.path.name}: the graph's inputs {inputs} and outputs {outputs} are not those of its "
                             f"metadata (inputs {({k: v[1] + str(v[0]) for k, v in expected.items()})} with a batch "
                             f"dimension; outputs {OUTPUT_NAMES})")

    # ------------------------------------------------------------------ the contract
    @property
    def world(self):
        """The :class:`~sb3_crowdnav.sim.world.World` the model was trained in."""
        return self.metadata.world

    @property
    def schema(self) -> ObservationSchema:
        """The observation layout the graph takes."""
        return self.metadata.schema

    def check_env(self, env: Any, allow_env_mismatch: bool = False) -> None:
        """``ValueError`` when ``env``'s observation shapes are not the graph's or, unless ``allow_env_mismatch``, its
        world is not the one the model was trained in (naming each differing field)."""
        try:
            actual = ObservationSchema.from_space(env.observation_space)
        except (TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"{self.path.name} acts on sb3_crowdnav observations {self.schema.shapes}: {exc}") from None
        if actual != self.schema:
            raise ValueError(f"{self.path.name} was trained on observations {self.schema.shapes} but the env gives "
                             f"{actual.shapes}; use the env, max_humans and history_length it was trained with")
        env_world = world_of(env)
        if env_world is None:
            raise ValueError(f"{self.path.name}: the env publishes no world (env.unwrapped.world) to check the model's "
                             "against; give a sb3_crowdnav env")
        fields = PREDICTION_FIELDS if self.metadata.kind == "lookahead" else MOTION_FIELDS
        mismatch = compare_worlds(self.world, env_world, fields)
        if mismatch and not allow_env_mismatch:
            keywords = env_keywords(self.world, env_world, fields)
            hint = f"; to run it in its world, make the env with {', '.join(f'{k}={v!r}' for k, v in keywords.items())}" \
                if keywords else ""
            raise ValueError(f"{self.path.name}: {mismatch}{hint}; or pass allow_env_mismatch=True "
                             "(--allow-env-mismatch) to run it there anyway")

    # ------------------------------------------------------------------ acting
    def _feeds(self, observation: Any) -> tuple[dict[str, np.ndarray], bool]:
        """The graph's inputs (float32, (B, n) each) and whether ``observation`` was a batch."""
        if isinstance(observation, tuple) and len(observation) == 2 and isinstance(observation[1], dict):
            raise ValueError("predict() got a (obs, info) tuple: pass the observation only (Gym API vs VecEnv API)")
        if not isinstance(observation, Mapping):
            raise TypeError(f"observation must be a dict of arrays with the keys {list(self.metadata.keys)}, got "
                            f"{type(observation).__name__}")
        keys = self.metadata.keys
        missing, unknown = [k for k in keys if k not in observation], sorted(set(observation) - set(keys))
        if missing or unknown:
            raise ValueError(f"observation must have exactly the keys {list(keys)}; missing {missing}, unknown {unknown}")
        arrays = {k: np.asarray(observation[k], dtype=np.float32) for k in keys}
        batched = arrays["robot"].ndim == 2
        shapes = self.metadata.schema.shapes
        batch = arrays["robot"].shape[0] if batched else None
        wanted = {k: ((batch, *s) if batched else s) for k, s in shapes.items()}
        if any(arrays[k].shape != wanted[k] for k in keys) or batch == 0:
            raise ValueError(f"observation shapes {({k: a.shape for k, a in arrays.items()})} are not the graph's "
                             f"{shapes} (one observation) or (B, ...) of them with B >= 1")
        feeds = {k: np.ascontiguousarray(a if batched else a[None]) for k, a in arrays.items()}
        if self.metadata.braking_steps is not None:
            self._check_braking(feeds["robot"])
        return feeds, batched

    def _check_braking(self, robot: np.ndarray) -> None:
        """``ValueError`` when a robot of the batch could leave an action faster than the graph's stopping check
        brakes to a stand (:attr:`~sb3_crowdnav.deploy.metadata.GraphMetadata.braking_speed`): its velocity, or its
        v_pref times the table's fastest action."""
        meta = self.metadata
        speed = np.maximum(np.hypot(robot[:, Robot.VEL][:, 0], robot[:, Robot.VEL][:, 1]),
                           robot[:, Robot.V_PREF].astype(np.float64) * self._fastest)
        if np.any(speed > meta.braking_speed * (1 + 1e-9)):
            raise ValueError(f"observation['robot']: a speed of {float(speed.max()):.3f} m/s (velocity, or v_pref x "
                             f"the fastest action) is beyond the {meta.braking_speed:.3f} m/s the graph's stopping "
                             f"check brakes from ({meta.braking_steps} steps at max_acceleration "
                             f"{meta.world.max_acceleration} m/s^2); export for this robot's v_pref")

    def _mask_feed(self, action_masks: Any, batch: int, batched: bool) -> np.ndarray:
        """The graph's :data:`~sb3_crowdnav.deploy.metadata.MASK_INPUT`, (B, A) bool, of sb3-contrib's
        ``action_masks`` (True: allowed), (A,) for one observation or (B, A) for a batch."""
        meta = self.metadata
        if MASK_INPUT not in meta.inputs:
            raise ValueError(f"{self.path.name} takes no action masks: it is the greedy decision of a {meta.policy} "
                             f"(kind {meta.kind!r}); masks go to a graph exported from a MaskablePPO model")
        masks = np.asarray(action_masks)
        if masks.dtype != np.bool_ and not (np.issubdtype(masks.dtype, np.integer) and np.isin(masks, (0, 1)).all()):
            raise TypeError(f"action_masks must be booleans (True: allowed) or 0/1 integers, got {masks.dtype}")
        wanted = (batch, meta.world.n_actions) if batched else (meta.world.n_actions,)
        if masks.shape != wanted:
            raise ValueError(f"action_masks must have the shape {wanted} of the observation, got {masks.shape}")
        return np.ascontiguousarray(masks.astype(np.bool_).reshape(batch, -1))

    def run(self, observation: Any, action_masks: Any = None) -> tuple[np.ndarray, np.ndarray, bool]:
        """The graph's outputs ``(action (B,), action_values (B, A))`` for an observation, and whether it was a batch.

        :param action_masks: a MaskablePPO graph's masks (True: allowed; (A,) or (B, A) like the observation), or
            None for every action allowed
        """
        feeds, batched = self._feeds(observation)
        batch = len(feeds["robot"])
        if action_masks is not None:
            feeds[MASK_INPUT] = self._mask_feed(action_masks, batch, batched)
        elif MASK_INPUT in self.metadata.inputs:  # every action allowed
            feeds[MASK_INPUT] = np.ones((batch, self.metadata.world.n_actions), dtype=np.bool_)
        action, values = self.session.run(list(OUTPUT_NAMES), feeds)
        return action, values, batched

    def action_values(self, observation: Any, action_masks: Any = None) -> np.ndarray:
        """The values the greedy action maximises, (B, n_actions) (for one observation (1, n_actions))."""
        return self.run(observation, action_masks)[1]

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True,
                action_masks: Any = None) -> tuple[np.ndarray, Any]:
        """The greedy action(s), with SB3's ``predict`` signature (and sb3-contrib MaskablePPO's ``action_masks``,
        for a graph exported from one): an action for one observation, an array (B,) for a batch; ``state`` comes
        back as it was given (the graph has none)."""
        if not deterministic:
            raise ValueError("an exported graph holds the greedy decision only: deterministic=False (exploration, "
                             "sampled actions) is not in it")
        action, _, batched = self.run(observation, action_masks)
        return (action if batched else action[0]), state

    def __repr__(self) -> str:
        meta = self.metadata
        return f"OnnxPolicy({str(self.path)!r}, {meta.policy} ({meta.extractor}), {meta.kind}, {meta.world.n_actions} actions)"


__all__ = ["OPTIMIZATION_LEVELS", "OnnxPolicy"]
