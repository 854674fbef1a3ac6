"""What an exported graph carries besides the graph: the world contract and the observation layout, as plain JSON.

An ONNX file's ``metadata_props`` map text keys to text values; a robot's stack reads them with any ONNX runtime
(``Ort::ModelMetadata::GetCustomMetadataMapKeys`` in C++, ``session.get_modelmeta().custom_metadata_map`` in
Python). :class:`GraphMetadata` writes these entries, each value one JSON document (:data:`KEYS`), and reads them
back: strictly (JSON only, no ``NaN``; every key present; the world through :meth:`World.from_dict`; the layout and
the action table checked against the world and the schema), so a file that was edited or written by something else
is refused with a message naming the entry instead of steering a robot by a wrong contract.
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from sb3_crowdnav.sim.actions import STOP_ACTION
from sb3_crowdnav.sim.observation import HUMAN_FIELDS, ROBOT_FIELDS, ObservationSchema
from sb3_crowdnav.sim.validation import check_choice, check_int, check_number
from sb3_crowdnav.sim.world import World
from sb3_crowdnav.version import __version__

FORMAT = 4  # the version of this layout of metadata_props; a reader refuses a newer one (2: braking_steps, 3: planning_depth,
# 4: planning_width)
OPSET = 18  # the ONNX opset of the exported graphs (torch.onnx's dynamo exporter implements 18 and above)
PREFIX = "sb3_crowdnav."
KEYS = ("format", "version", "decision", "world", "observation", "actions", "robot")  # each PREFIX + key
KINDS = ("lookahead", "q_values", "logits", "masked_logits")
OUTPUT_NAMES = ("action", "action_values")  # the graph's outputs
MASK_INPUT = "action_masks"  # the input after the observation's of a "masked_logits" graph: (B, A) bool, True: allowed
INSTALL_HINT = 'pip install "sb3-crowdnav[deploy]"'


def require(module: str, purpose: str) -> ModuleType:
    """Import an optional dependency of :mod:`sb3_crowdnav.deploy`, or ``ImportError`` with the install hint."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"{purpose} needs the package {module!r}, which is not installed: {INSTALL_HINT}") from exc


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not plain JSON")


def _json(entry: str, text: Any) -> Any:
    """Parse one metadata value: JSON text only (``NaN`` and ``Infinity`` are refused)."""
    if not isinstance(text, str):
        raise TypeError(f"metadata entry {PREFIX}{entry} must be text, got {type(text).__name__}")
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except ValueError as exc:
        raise ValueError(f"metadata entry {PREFIX}{entry} is not plain JSON: {exc}") from None


def _mapping(entry: str, value: Any, keys: tuple[str, ...]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping) or set(value) != set(keys):
        got = sorted(value) if isinstance(value, Mapping) else type(value).__name__
        raise ValueError(f"metadata entry {PREFIX}{entry} must be a JSON object with the keys {sorted(keys)}, got {got}")
    return value


DECISION_KEYS = ("kind", "policy", "extractor", "ensemble_size", "pedestrian_model", "gamma", "braking_steps",
                 "planning_depth", "planning_width", "opset", "outputs")
OBSERVATION_KEYS = ("keys", "shapes", "dtype", "history_length", "max_humans", "max_obstacles", "num_waypoints",
                    "robot_fields", "human_fields", "frame")
ACTION_KEYS = ("n_actions", "kinematics", "speed_fractions", "directions", "stop_action")
ROBOT_KEYS = ("radius", "v_pref", "time_step", "max_acceleration", "max_turn_rate")
OUTPUTS = {
    "action": "the greedy action index (B,) int64: the argmax of action_values (the first on ties)",
    "action_values": {"lookahead": "R(s, a) + γ^(Δt·v_pref)·V(s') of every action (B, A) float64",
                      "q_values": "Q(s, a) of every action (B, A) float32",
                      "logits": "the actor's logits of every action (B, A) float32",
                      "masked_logits": f"the actor's logits of every action, -1e8 where the input {MASK_INPUT} (B, A) "
                                       "bool is False (B, A) float32"},
}


@dataclass(frozen=True)
class GraphMetadata:
    """The contract of an exported decision graph.

    :param kind: what ``action_values`` holds: ``"lookahead"`` (APGValue), ``"q_values"`` (DQN, QR-DQN's mean over
        the quantiles), ``"logits"`` (PPO, A2C), ``"masked_logits"`` (MaskablePPO: a graph with the input
        :data:`MASK_INPUT` too)
    :param world: the world the model was trained in (Δt, kinematics, action table, limits, reward, waypoint rule)
    :param schema: the observation's layout (T, max_humans and, in the warehouse, segments and waypoints)
    :param robot_radius: the radius of the robot the model was trained for [m]
    :param robot_v_pref: its preferred speed [m/s]; the action speeds are ``v_pref x speed_fractions``
    :param policy: the class of the exported policy
    :param extractor: the class of its observation encoder
    :param ensemble_size: value networks averaged (a lookahead ensemble), else 1
    :param pedestrian_model: the lookahead's pedestrian model (None for SB3 policies)
    :param gamma: the lookahead's discount per second at v_pref = 1 (None for SB3 policies)
    :param braking_steps: the braking sub-steps of the lookahead's stopping-distance check
        (:func:`~sb3_crowdnav.deploy.propagation.braking_steps`); None: the graph has no such check
    :param planning_depth: the steps the lookahead searches before V (1: one step); None for SB3 policies
    :param planning_width: the actions of each step a deeper search expands (None: every one, and for SB3 policies)
    :param version: the sb3_crowdnav version that wrote the file
    :param opset: the graph's ONNX opset
    """

    kind: str
    world: World
    schema: ObservationSchema
    robot_radius: float
    robot_v_pref: float
    policy: str
    extractor: str
    ensemble_size: int = 1
    pedestrian_model: str | None = None
    gamma: float | None = None
    braking_steps: int | None = None
    planning_depth: int | None = None
    planning_width: int | None = None
    version: str = __version__
    opset: int = OPSET

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, KINDS)
        if not isinstance(self.world, World):
            raise TypeError(f"world must be a World, got {type(self.world).__name__}")
        if not isinstance(self.schema, ObservationSchema):
            raise TypeError(f"schema must be an ObservationSchema, got {type(self.schema).__name__}")
        check_number("robot_radius", self.robot_radius)
        check_number("robot_v_pref", self.robot_v_pref)
        check_int("ensemble_size", self.ensemble_size, 1)
        check_int("opset", self.opset, 1)
        for name in ("policy", "extractor", "version"):
            if not isinstance(getattr(self, name), str):
                raise TypeError(f"{name} must be a str, got {type(getattr(self, name)).__name__}")
        if (self.kind == "lookahead") != (self.gamma is not None) or (self.gamma is None) != (self.pedestrian_model is None):
            raise ValueError(f"gamma and pedestrian_model are set for a lookahead only (kind {self.kind!r}), got "
                             f"{self.gamma!r} and {self.pedestrian_model!r}")
        if (self.kind == "lookahead") != (self.planning_depth is not None):
            raise ValueError(f"planning_depth is set for a lookahead only (kind {self.kind!r}), got {self.planning_depth!r}")
        if self.planning_depth is not None:
            check_int("planning_depth", self.planning_depth, 1)
        if self.planning_width is not None:
            check_int("planning_width", self.planning_width, 1)
            if self.planning_depth is None or self.planning_depth == 1:
                raise ValueError(f"planning_width is set for a lookahead of planning_depth > 1 only, got "
                                 f"{self.planning_width!r} with planning_depth {self.planning_depth!r}")
        if self.braking_steps is not None:
            check_int("braking_steps", self.braking_steps, 1)
            if self.kind != "lookahead" or self.world.max_acceleration is None:
                raise ValueError("braking_steps is set for a lookahead in a world with max_acceleration only (kind "
                                 f"{self.kind!r}, max_acceleration {self.world.max_acceleration!r}), got "
                                 f"{self.braking_steps!r}")

    @property
    def fastest_fraction(self) -> float:
        """The action table's largest speed fraction (speeds are ``v_pref`` times the fractions)."""
        return float(np.max(self.world.action_table(1.0)[0]))

    @property
    def braking_speed(self) -> float | None:
        """The fastest robot [m/s] the graph's stopping check brakes to a stand (braking_steps·a_max·Δt), or None."""
        if self.braking_steps is None:
            return None
        return self.braking_steps * self.world.max_acceleration * self.world.time_step

    @property
    def keys(self) -> tuple[str, ...]:
        """The observation's keys, in order: the graph's first inputs."""
        return tuple(self.schema.shapes)

    @property
    def inputs(self) -> tuple[str, ...]:
        """The graph's inputs: the observation's keys, then :data:`MASK_INPUT` for ``"masked_logits"``."""
        return (*self.keys, MASK_INPUT) if self.kind == "masked_logits" else self.keys

    # ------------------------------------------------------------------ writing
    def props(self) -> dict[str, str]:
        """The ``metadata_props`` entries: :data:`PREFIX` + each of :data:`KEYS`, JSON text."""
        world, schema = self.world, self.schema
        speeds, directions = world.action_table(1.0)
        entries = {
            "format": FORMAT,
            "version": self.version,
            "decision": {"kind": self.kind, "policy": self.policy, "extractor": self.extractor,
                         "ensemble_size": self.ensemble_size, "pedestrian_model": self.pedestrian_model,
                         "gamma": self.gamma, "braking_steps": self.braking_steps,
                         "planning_depth": self.planning_depth, "planning_width": self.planning_width,
                         "opset": self.opset,
                         "outputs": {"action": OUTPUTS["action"], "action_values": OUTPUTS["action_values"][self.kind]}},
            "world": world.to_dict(),
            "observation": {"keys": list(self.keys), "shapes": {k: list(s) for k, s in schema.shapes.items()},
                            "dtype": "float32", "history_length": schema.history_length,
                            "max_humans": schema.max_humans, "max_obstacles": schema.max_obstacles,
                            "num_waypoints": schema.num_waypoints, "robot_fields": list(ROBOT_FIELDS),
                            "human_fields": list(HUMAN_FIELDS), "frame": "world"},
            "actions": {"n_actions": world.n_actions, "kinematics": world.kinematics,
                        "speed_fractions": speeds.tolist(), "directions": directions.tolist(),
                        "stop_action": STOP_ACTION if world.actions == "with_stop" else None},
            "robot": {"radius": self.robot_radius, "v_pref": self.robot_v_pref, "time_step": world.time_step,
                      "max_acceleration": world.max_acceleration, "max_turn_rate": world.max_turn_rate},
        }
        return {PREFIX + key: json.dumps(value, allow_nan=False) for key, value in entries.items()}

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_props(cls, props: Mapping[str, str]) -> GraphMetadata:
        """Read :meth:`props`' entries back; ``ValueError`` naming the entry that is missing, not plain JSON, of a
        newer format, or inconsistent with the world it embeds."""
        missing = [PREFIX + key for key in KEYS if PREFIX + key not in props]
        if missing:
            raise ValueError(f"the graph's metadata lacks {missing}: it was not written by sb3_crowdnav.deploy.export_onnx")
        data = {key: _json(key, props[PREFIX + key]) for key in KEYS}
        if not isinstance(data["format"], int) or isinstance(data["format"], bool) or data["format"] > FORMAT:
            raise ValueError(f"metadata entry {PREFIX}format is {data['format']!r}; this sb3_crowdnav reads format "
                             f"<= {FORMAT}: update sb3_crowdnav")
        decision = data["decision"]
        if data["format"] == 1 and isinstance(decision, Mapping) and "braking_steps" not in decision:
            decision = {**decision, "braking_steps": None}  # format 1 came before the stopping check
        if data["format"] <= 2 and isinstance(decision, Mapping) and "planning_depth" not in decision:
            # formats 1 and 2 came before deeper searches: a lookahead of one step
            decision = {**decision, "planning_depth": 1 if decision.get("kind") == "lookahead" else None}
        if data["format"] <= 3 and isinstance(decision, Mapping) and "planning_width" not in decision:
            decision = {**decision, "planning_width": None}  # formats 1 to 3 came before beams: every successor
        decision = _mapping("decision", decision, DECISION_KEYS)
        observation = _mapping("observation", data["observation"], OBSERVATION_KEYS)
        robot = _mapping("robot", data["robot"], ROBOT_KEYS)
        try:
            world = World.from_dict(data["world"])
            schema = ObservationSchema(observation["history_length"], observation["max_humans"],
                                       observation["max_obstacles"], observation["num_waypoints"])
            meta = cls(kind=decision["kind"], world=world, schema=schema, robot_radius=robot["radius"],
                       robot_v_pref=robot["v_pref"], policy=decision["policy"], extractor=decision["extractor"],
                       ensemble_size=decision["ensemble_size"], pedestrian_model=decision["pedestrian_model"],
                       gamma=decision["gamma"], braking_steps=decision["braking_steps"],
                       planning_depth=decision["planning_depth"], planning_width=decision["planning_width"],
                       version=data["version"],
                       opset=decision["opset"])
        except (TypeError, ValueError) as exc:
            raise ValueError(f"the graph's metadata is not a valid contract: {exc}") from None
        written = json.loads(meta.props()[PREFIX + "observation"])
        if observation != written:
            raise ValueError(f"metadata entry {PREFIX}observation does not match its own schema: {observation} "
                             f"(expected {written})")
        expected = {key: json.loads(meta.props()[PREFIX + key]) for key in ("actions", "robot")}
        actions = _mapping("actions", data["actions"], ACTION_KEYS)
        tables = ("speed_fractions", "directions")
        if {k: v for k, v in actions.items() if k not in tables} != {k: v for k, v in expected["actions"].items()
                                                                        if k not in tables} \
                or not all(_same_table(actions[k], expected["actions"][k]) for k in tables):
            raise ValueError(f"metadata entry {PREFIX}actions does not match the world's action table "
                             f"({world.actions!r}, rotation_range={world.rotation_range})")
        if robot != expected["robot"]:
            raise ValueError(f"metadata entry {PREFIX}robot does not match the world: {dict(robot)} (the world has "
                             f"{expected['robot']})")
        return meta


def _same_table(values: Any, table: list[float]) -> bool:
    """Whether a JSON list of numbers equals ``table`` to 1e-9."""
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return array.shape == (len(table),) and bool(np.allclose(array, table, rtol=0, atol=1e-9))


__all__ = ["FORMAT", "INSTALL_HINT", "KEYS", "KINDS", "MASK_INPUT", "OPSET", "OUTPUT_NAMES", "PREFIX", "GraphMetadata",
           "require"]
