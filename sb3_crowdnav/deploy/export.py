"""``export_onnx``: a trained model's whole greedy decision as one ONNX graph with its contract as metadata.

The graph goes from the observation's tensors (the env's ``Dict`` keys as named float32 inputs, batch dimension
``batch`` dynamic) to ``action`` (the greedy action index, int64) and ``action_values`` (the values it maximises):
for ``APGValue`` the whole lookahead (:mod:`sb3_crowdnav.deploy.graph`), for SB3's DQN the Q network, for PPO/A2C
the actor, for sb3-contrib's QR-DQN the mean of the quantile network, for MaskablePPO the actor with a second input,
the action masks (every action allowed: a mask of all True). It is written by torch's ONNX
exporter (``torch.onnx.export(..., dynamo=True)``) in opset :data:`~sb3_crowdnav.deploy.metadata.OPSET`, with the
translations it lacks: ``hypot`` (as ``sqrt(x² + y²)``), the stable ``sort`` (as ``TopK``, which orders ties by
index, as a stable sort does) and the extractors' LSTM operator (as ONNX's ``LSTM`` with ``sequence_lens``). A
lookahead's value network runs as the body of a ``Scan`` over the batch's observations (:func:`to_onnx`). The file
holds the weights (no external data) and :class:`~sb3_crowdnav.deploy.metadata.GraphMetadata`'s entries.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch as th

from sb3_crowdnav.deploy.graph import LookaheadDecision, MaskedActorDecision, decision_module, policy_of
from sb3_crowdnav.deploy.metadata import OPSET, OUTPUT_NAMES, GraphMetadata, require
from sb3_crowdnav.deploy.runtime import OnnxPolicy
from sb3_crowdnav.models import load_model, resolve_model_path
from sb3_crowdnav.nn.extractors import ApgExtractor, CadrlExtractor
from sb3_crowdnav.serialization import read_world, world_of
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import ObservationSchema, Robot
from sb3_crowdnav.sim.world import MOTION_FIELDS, PREDICTION_FIELDS, World, compare_worlds


def export_onnx(model: Any, path: str | Path, *, env: Any = None, world: World | Mapping[str, Any] | None = None) -> Path:
    """Write ``model``'s greedy decision as one ONNX graph at ``path`` (see the module docstring); returns the path.

    :param model: a trained ``APGValue``, ``DQN``, ``PPO``, ``A2C``, ``QRDQN`` or ``MaskablePPO`` model (or its
        policy), or the path of one saved as ``.zip`` (loaded without unpickling; its world read from the file).
        Other models (``RecurrentPPO``: its LSTM state) are refused with a ``ValueError`` naming them
    :param path: the ``.onnx`` file to write
    :param env: the env the model acts in: its robot's radius and v_pref are recorded (default: the package's robot,
        0.3 m and 1 m/s), and a model trained in another world or on other observation shapes is refused
    :param world: the world of an SB3 model object, which does not hold one (its saved file does; so does an
        ``APGValue`` model, whose own world is used)
    """
    source = None
    if isinstance(model, (str, Path)):
        source = resolve_model_path(model)
        model = load_model(source)
    decision = decision_module(model)  # refuses what it cannot export, before any work
    policy = policy_of(model)
    schema = ObservationSchema.from_space(policy.observation_space)
    trained = _trained_world(policy, world, source, env)
    radius, v_pref = SceneConfig.robot_radius, SceneConfig.robot_v_pref
    if env is not None:
        _check_env(env, schema, trained, isinstance(decision, LookaheadDecision))
        scene = env.get_attr("scene")[0] if hasattr(env, "get_attr") else env.unwrapped.scene
        radius, v_pref = scene.robot_radius, scene.robot_v_pref
    extractor = getattr(policy, "features_extractor_class", None)
    lookahead = isinstance(decision, LookaheadDecision)
    if lookahead:  # the stopping check brakes for this robot's speed
        decision.brake_for(v_pref)
    metadata = GraphMetadata(
        kind=decision.kind, world=trained, schema=schema, robot_radius=float(radius), robot_v_pref=float(v_pref),
        policy=type(policy).__name__, extractor=getattr(extractor, "__name__", str(extractor)),
        ensemble_size=getattr(policy, "ensemble_size", 1),
        pedestrian_model=policy.pedestrian_model if lookahead else None, gamma=policy.gamma if lookahead else None,
        braking_steps=decision.propagation.braking_steps if lookahead else None,
        planning_depth=decision.depth if lookahead else None,
        planning_width=decision.width if lookahead else None,
    )
    proto = to_onnx(decision, schema)
    onnx = require("onnx", "export_onnx")
    proto.producer_name, proto.producer_version = "sb3_crowdnav", metadata.version
    proto.doc_string = f"sb3_crowdnav {metadata.policy} ({metadata.extractor}): observation -> greedy action"
    onnx.helper.set_model_props(proto, metadata.props())
    onnx.checker.check_model(proto)
    path = Path(path)
    onnx.save_model(proto, str(path))
    try:  # the file as a robot reads it: the graph loads in ONNX Runtime, the metadata reads back
        OnnxPolicy(path)
    except ValueError as exc:
        path.unlink(missing_ok=True)
        raise RuntimeError(f"the exported graph does not load in ONNX Runtime, an exporter bug: {exc}") from exc
    return path


def _trained_world(policy: Any, world: World | Mapping[str, Any] | None, source: Path | None, env: Any) -> World:
    """The world the model was trained in: a lookahead's own, else ``world``, the saved file's or the env's."""
    given = None if world is None else World.coerce(world)
    own = getattr(policy, "world", None)
    if isinstance(own, World):
        if given is not None and (diff := compare_worlds(own, given, against="world=")):
            raise ValueError(f"world= differs from the world the model holds: {diff}; leave world= out")
        return own
    found = given or (read_world(source) if source is not None else None) or (world_of(env) if env is not None else None)
    if found is None:
        raise ValueError(f"{type(policy).__name__} holds no world: pass world= (the env's env.unwrapped.world) or env=, "
                         "or export the model's saved file, which records it")
    return found


def _check_env(env: Any, schema: ObservationSchema, trained: World, lookahead: bool) -> None:
    """``ValueError`` when the env's observations or world are not the model's."""
    actual = ObservationSchema.from_space(env.observation_space)
    if actual != schema:
        raise ValueError(f"the model was trained on observations {schema.shapes} but the env gives {actual.shapes}")
    env_world = world_of(env)
    if env_world is None:
        raise ValueError(f"env must be a sb3_crowdnav env (it publishes its world), got {type(env).__name__}")
    mismatch = compare_worlds(trained, env_world, PREDICTION_FIELDS if lookahead else MOTION_FIELDS)
    if mismatch:
        raise ValueError(f"{mismatch}; export it with an env of the world it was trained in")


def example_observation(schema: ObservationSchema, batch: int = 2) -> dict[str, th.Tensor]:
    """A batch of plausible observations to trace with (zeros, everyone present, a robot of radius 0.3 m at 1 m/s)."""
    obs = {key: th.zeros(batch, *shape) for key, shape in schema.shapes.items()}
    obs["robot"][:, Robot.RADIUS] = SceneConfig.robot_radius
    obs["robot"][:, Robot.V_PREF] = SceneConfig.robot_v_pref
    for key in obs:
        if key.endswith("mask"):
            obs[key] += 1.0
    return obs


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the exporter's progress lines and warnings (about torchvision, LSTM weights, deprecations)."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)


PLACEHOLDER_DOMAIN = "sb3_crowdnav"  # the domain of graph.values_per_observation until the export replaces it


class _ValueNetwork(th.nn.Module):
    """A lookahead's value network as a module of the observation dict alone: V of each row, (N,)."""

    def __init__(self, value_net: th.nn.Module) -> None:
        super().__init__()
        self.value_net = value_net

    def forward(self, observation: dict[str, th.Tensor]) -> th.Tensor:
        return self.value_net(observation)


def to_onnx(decision: th.nn.Module, schema: ObservationSchema) -> Any:
    """The ``onnx.ModelProto`` of a decision module (:mod:`sb3_crowdnav.deploy.graph`), inputs named by the
    observation's keys with a dynamic batch dimension.

    A lookahead's value network is exported on its own and runs in the graph as the body of a ``Scan`` over the
    batch's observations, on one observation's A propagated states at a time (:func:`_splice_values`)."""
    per_iteration = observations_per_iteration(decision, schema) if isinstance(decision, LookaheadDecision) else None
    if isinstance(decision, LookaheadDecision):
        decision.scan = per_iteration is not None
    proto = _export(decision, schema, OUTPUT_NAMES)
    if per_iteration is not None:
        _splice_values(proto, _export(_ValueNetwork(decision.value_net), schema, ("value",)), schema, per_iteration)
    return proto


def _export(module: th.nn.Module, schema: ObservationSchema, output_names: tuple[str, ...]) -> Any:
    """torch's ONNX export of ``module(observation)`` with the translations the exporter lacks."""
    onnx = require("onnx", "export_onnx")
    onnxscript = require("onnxscript", "export_onnx")
    op = onnxscript.opset18
    schema_ = onnx.defs.OpSchema
    placeholder = onnxscript.values.Op(onnxscript.values.Opset(PLACEHOLDER_DOMAIN, 1), "ValuesPerObservation", schema_(
        "ValuesPerObservation", PLACEHOLDER_DOMAIN, 1,
        inputs=[schema_.FormalParameter("observation", "T", param_option=schema_.FormalParameterOption.Variadic)],
        outputs=[schema_.FormalParameter("values", "T")], type_constraints=[("T", ["tensor(float)"], "")],
        attributes=[schema_.Attribute("n_actions", schema_.AttrType.INT, "")]))

    def hypot(x, y):
        return op.Sqrt(op.Add(op.Mul(x, x), op.Mul(y, y)))

    def stable_sort(x, stable=None, dim: int = -1, descending: bool = False):
        count = op.Gather(op.Shape(x), op.Constant(value_ints=[dim]))
        return op.TopK(x, count, axis=dim, largest=descending, sorted=True)  # ties in index order, as stable

    def lstm_last_state(sequence, lengths, weight_ih, weight_hh, bias_ih, bias_hh, hidden_size: int):
        # ONNX's gate order is (input, output, forget, cell), torch's (input, forget, cell, output)
        order = op.Constant(value_ints=[g * hidden_size + k for g in (0, 3, 1, 2) for k in range(hidden_size)])
        first = op.Constant(value_ints=[0])

        def gates(weight):
            return op.Unsqueeze(op.Gather(weight, order, axis=0), first)

        bias = op.Concat(gates(bias_ih), gates(bias_hh), axis=1)
        _, last, _ = op.LSTM(op.Transpose(sequence, perm=[1, 0, 2]), gates(weight_ih), gates(weight_hh), bias,
                             op.Cast(lengths, to=onnx.TensorProto.INT32), hidden_size=hidden_size)
        return op.Squeeze(last, first)  # Y_h: the state after each row's own length

    def values_per_observation(observation, n_actions: int):
        return placeholder(*observation, n_actions=n_actions)

    example = example_observation(schema)
    extra = module.example_inputs(len(example["robot"])) if isinstance(module, MaskedActorDecision) else {}
    batch = th.export.Dim("batch")
    modes = [(module, module.training) for module in module.modules()]  # the model's own, restored after
    module.eval()
    try:
        with _quiet(), th.no_grad():
            program = th.onnx.export(
                module, (), kwargs={"observation": example, **extra}, dynamo=True, opset_version=OPSET, verbose=False,
                input_names=[*example, *extra], output_names=list(output_names),
                dynamic_shapes={"observation": {key: {0: batch} for key in example}, **{k: {0: batch} for k in extra}},
                custom_translation_table={th.ops.aten.hypot.default: hypot, th.ops.aten.sort.stable: stable_sort,
                                          th.ops.sb3_crowdnav.lstm_last_state.default: lstm_last_state,
                                          th.ops.sb3_crowdnav.values_per_observation.default: values_per_observation},
            )
    finally:
        for submodule, mode in modes:
            submodule.training = mode
    proto = program.model_proto
    names = [value.name for value in proto.graph.input]
    if names != [*example, *extra]:  # the dict's order is the inputs' order; a reordering would swap tensors of a shape
        raise RuntimeError(f"the exported graph's inputs are {names}, expected {[*example, *extra]}")
    return proto



ROWS_PER_ITERATION = 6400  # the most rows of the value network's layers a Scan iteration takes (see below)


def observations_per_iteration(decision: LookaheadDecision, schema: ObservationSchema) -> int | None:
    """At most how many observations' A propagated states one iteration of the value network's ``Scan`` takes;
    None: no ``Scan``, the network inline (CADRL, whose one row per state keeps a batch's activations small: there
    the ``Scan``'s copy of the inputs made the batch of 64 6 % slower than ONNX Runtime's single pass).

    An iteration's layers run on at most :data:`ROWS_PER_ITERATION` rows (pedestrian slots x history steps the
    encoder reads x states) and one observation at least, so that their activations stay in the CPU's caches:
    ``apg_rl``'s value network (80 states x 5 steps x 6 pedestrians per observation) ran 1.8x faster one
    observation at a time than on a batch of 64 in one pass; ``sf_rl``'s graph (80 x 6 rows per observation) was
    fastest with 4 to 8 observations an iteration, 1.1-1.2x its speed without the ``Scan``; smaller iterations
    lose more to the per-operator overhead than they gain. This gives 1 observation for the APG encoders, 8 for
    SF, LM and LSTM-RL.
    """
    net = decision.value_net
    extractor = (net.members[0] if hasattr(net, "members") else net).features_extractor
    if isinstance(extractor, CadrlExtractor):  # one row per state: the nearest pedestrian
        return None
    # a row per pedestrian slot and, for the APG encoder, per history step (the others read the latest)
    rows = schema.max_humans * (schema.history_length if isinstance(extractor, ApgExtractor) else 1)
    return max(1, ROWS_PER_ITERATION // (decision.propagation.world.n_actions * rows))


def _splice_values(proto: Any, value_net: Any, schema: ObservationSchema, per_iteration: int) -> None:
    """Replace each of the decision's placeholders for V (:func:`~sb3_crowdnav.deploy.graph.values_per_observation`:
    one, or one per step of a beam search) by ``Scan(body=value_net)`` over its observations, at most
    ``per_iteration`` at a time, in place (:func:`_scan_values`)."""
    onnx = require("onnx", "export_onnx")
    graph = proto.graph
    stubs = [node for node in graph.node if node.domain == PLACEHOLDER_DOMAIN]
    if not stubs:
        raise RuntimeError("the exported decision holds no placeholder of its value network")
    for index, stub in enumerate(stubs):
        suffix = f"_{index}" if index else ""
        body = onnx.compose.add_prefix_graph(value_net.graph, f"value_net{suffix}/")  # no name shadows another
        position = list(graph.node).index(stub)
        spliced = [*graph.node[:position], *_scan_values(graph, stub, body, schema, per_iteration, suffix),
                   *graph.node[position + 1:]]
        del graph.node[:]
        graph.node.extend(spliced)
    proto.functions.extend(value_net.functions)
    domains = {entry.domain for entry in proto.opset_import}
    proto.opset_import.extend(entry for entry in value_net.opset_import if entry.domain not in domains)
    imports = [entry for entry in proto.opset_import if entry.domain != PLACEHOLDER_DOMAIN]
    del proto.opset_import[:]
    proto.opset_import.extend(imports)


def _scan_values(graph: Any, stub: Any, body: Any, schema: ObservationSchema, per_iteration: int,
                 suffix: str) -> list[Any]:
    """The nodes that compute the placeholder ``stub``'s output by ``Scan(body)`` (constants go into ``graph``'s
    initializers; the Scan node is named ``value_net_per_observation`` + ``suffix``).

    The placeholder takes the B x A propagated tensors (B * A, n) in the schema's key order, the value network's
    inputs. For B observations the graph runs ``I = ceil(B / per_iteration)`` iterations of ``k = ceil(B / I)``
    observations (one observation is one iteration of one, never a padded block): each tensor becomes (B, A, n),
    is padded with copies of the last observation to I x k observations (fewer than I copies) and cut into
    (I, k * A, n); the ``Scan`` feeds the body one block and stacks its V, and the padding's values are cut off.
    """
    onnx = require("onnx", "export_onnx")
    helper, int64 = onnx.helper, onnx.TensorProto.INT64
    n_actions = helper.get_attribute_value(next(a for a in stub.attribute if a.name == "n_actions"))
    for value in body.input:  # one block of states per iteration
        value.type.tensor_type.shape.dim[0].dim_param = "block"
    values = stub.output[0]
    nodes = []

    def constant(name: str, data: list[int]) -> str:
        graph.initializer.append(helper.make_tensor(f"{values}/{name}_constant", int64, [len(data)], data))
        return f"{values}/{name}_constant"

    def node(op_type: str, inputs: list[str], output: str, **attributes) -> str:
        nodes.append(helper.make_node(op_type, inputs, [f"{values}/{output}"], **attributes))
        return f"{values}/{output}"

    one = constant("one", [1])

    def ceil_div(numerator: str, denominator: str, output: str) -> str:  # (a + b - 1) // b of positive int64
        minus_one = node("Sub", [denominator, one], f"{output}_minus_one")
        return node("Div", [node("Add", [numerator, minus_one], f"{output}_sum"), denominator], output)

    rows = node("Shape", [stub.input[0]], "rows", start=0, end=1)  # B * A
    actions = constant("n_actions", [n_actions])
    batch = node("Div", [rows, actions], "batch")
    iterations = ceil_div(batch, constant("per_iteration", [per_iteration]), "iterations")
    per_block = ceil_div(batch, iterations, "per_block")
    padding = node("Sub", [node("Mul", [iterations, per_block], "padded"), batch], "padding")
    pads = node("Concat", [constant("pads_before", [0, 0, 0]), padding, constant("pads_after", [0, 0])], "pads", axis=0)
    block_rows = node("Mul", [per_block, actions], "block_rows")
    blocks = []
    for key, name in zip(schema.shapes, stub.input, strict=True):
        width = constant(f"{key}/width", [schema.shapes[key][0]])
        observations = constant(f"{key}/observations", [-1, n_actions, schema.shapes[key][0]])
        per_observation = node("Reshape", [name, observations], f"{key}/observations")
        padded = node("Pad", [per_observation, pads], f"{key}/padded", mode="edge")
        shape = node("Concat", [iterations, block_rows, width], f"{key}/block_shape", axis=0)
        blocks.append(node("Reshape", [padded, shape], f"{key}/blocks"))
    scanned = node("Scan", blocks, "blocks", num_scan_inputs=len(blocks), body=body)
    nodes[-1].name = f"value_net_per_observation{suffix}"
    flat = node("Reshape", [scanned, constant("flat", [-1])], "flat")
    kept = node("Slice", [flat, constant("start", [0]), rows], "kept")  # the padding's rows cut off
    nodes.append(helper.make_node("Identity", [kept], [values]))
    return nodes


__all__ = ["example_observation", "export_onnx", "to_onnx"]
