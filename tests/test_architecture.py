"""The house rules of the package: floors with one-way doors, small modules, one owner of the observation schema, no
reach into another module's private attributes, no import circle, one validator module, one policy-grammar reader."""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_crowdnav"
# floor of each top-level part of the package; a module may import its own part or a strictly lower floor
FLOORS = {
    "sim": 0, "version": 0,
    "envs": 1, "nn": 1, "serialization": 1, "safety": 1,
    "imitation": 2,
    "apg_value": 3,
    "models": 4,
    "": 4.5,  # ``import sb3_crowdnav``: the public API, registers the envs; its __init__ imports up to floor 4
    "deploy": 4.7,  # exports a model (floor 4) as an ONNX graph; the evaluation runs the graph as a policy
    "evaluation": 5,
    "training": 6,
    "cli": 7,
}
MAX_LINES = 450


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _part(module: str) -> str:
    """``sb3_crowdnav.apg_value.policies`` -> ``apg_value``; ``sb3_crowdnav`` -> ``""``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _own_part(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    if rel.name == "__init__.py" and rel.parent == Path("."):
        return ""
    return rel.parts[0].removesuffix(".py")


def _imports(path: Path) -> list[tuple[int, str]]:
    """Every ``sb3_crowdnav`` module imported anywhere in the file (also inside functions), with its line."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "sb3_crowdnav"]
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "sb3_crowdnav":
            if node.module == "sb3_crowdnav":  # from sb3_crowdnav import imitation -> the subpackage
                found += [(node.lineno, f"sb3_crowdnav.{a.name}") if a.name in FLOORS else (node.lineno, "sb3_crowdnav")
                          for a in node.names]
            else:
                found.append((node.lineno, node.module))
    return found


def test_every_part_of_the_package_has_a_floor():
    parts = {_own_part(p) for p in _modules()}
    assert parts <= set(FLOORS), parts - set(FLOORS)


def test_imports_only_go_down():
    wrong = []
    for path in _modules():
        own = _own_part(path)
        for line, module in _imports(path):
            target = _part(module)
            if target != own and not FLOORS[target] < FLOORS[own]:
                wrong.append(f"{path.relative_to(PACKAGE)}:{line} ({own or 'sb3_crowdnav'}, floor {FLOORS[own]}) "
                             f"imports {module} (floor {FLOORS[target]})")
    assert not wrong, "\n".join(wrong)


def test_the_floor_check_sees_a_wrong_import(tmp_path):
    """The check above is not vacuous: a ground-floor module importing the evaluation is caught."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from sb3_crowdnav.evaluation.runner import run_episodes\n")
    assert _imports(bad) == [(2, "sb3_crowdnav.evaluation.runner")]
    assert not FLOORS[_part("sb3_crowdnav.evaluation.runner")] < FLOORS["sim"]


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_modules_are_small(path):
    lines = len(path.read_text().splitlines())
    limit = 400 if path.relative_to(PACKAGE) == Path("apg_value/apg_value.py") else MAX_LINES
    assert lines <= limit, f"{path.relative_to(PACKAGE)} has {lines} lines (at most {limit})"


def test_no_class_is_built_with_type():
    built = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "type" \
                    and len(node.args) == 3:
                built.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not built, built


def test_the_observation_keys_are_defined_once():
    """Only sim/observation.py spells out the key tuple or builds the observation Dict from literals."""
    owners = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Tuple, ast.Dict)):
                elts = node.elts if isinstance(node, ast.Tuple) else [k for k in node.keys if k is not None]
                keys = {e.value for e in elts if isinstance(e, ast.Constant)}
                if {"robot", "humans", "humans_mask"} <= keys:
                    owners.append(str(path.relative_to(PACKAGE)))
    assert set(owners) == {"sim/observation.py"}, owners


def test_schema_round_trip_and_env_space():
    import gymnasium as gym
    import numpy as np

    import sb3_crowdnav  # noqa: F401
    from sb3_crowdnav.sim.observation import ObservationSchema

    env = gym.make("CrowdNav-v0", max_humans=7)
    schema = ObservationSchema.from_space(env.observation_space)
    assert schema == env.unwrapped.schema == ObservationSchema(5, 7)
    assert {k: s.shape for k, s in env.observation_space.spaces.items()} == schema.shapes
    obs, _ = env.reset(seed=0)
    view = schema.humans_view(obs["humans"])
    assert view.shape == (5, 7, 5)
    np.testing.assert_array_equal(view[-1], env.unwrapped.sim.history[-1].astype(np.float32))
    np.testing.assert_array_equal(schema.flatten_humans(view), obs["humans"])
    batch = np.stack([obs["humans"]] * 3)
    assert schema.humans_view(batch).shape == (3, 5, 7, 5)


# ---------------------------------------------------------------- no reach into another module's private attributes
# Attributes with a leading underscore that belong to a public protocol, not to an object's insides.
PUBLIC_UNDERSCORED = {"_replace", "_asdict", "_fields", "_make"}  # namedtuple's API
# torch's oneDNN kernels have no public name: nn/layers.py probes and calls them, falling back when they are absent
ALLOWED_REACHES = {("nn/layers.py", "_linear_pointwise"), ("nn/layers.py", "_is_mkldnn_bf16_supported"),
                   ("sim/social_force_kernels.py", "_obj")}  # JuPedSim 1.4.2's compiled simulation (pinned)


def _own_private_names(tree: ast.AST) -> set[str]:
    """Private names a module defines: its functions and classes, the attributes and names it assigns, arguments."""
    owned = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            owned.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            owned.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            owned.add(node.id)
    return {name for name in owned if name.startswith("_")}


def private_reaches(source: str, name: str) -> list[str]:
    """``obj._attr`` where ``obj`` is not ``self``, ``cls`` or ``super()`` and this module does not define
    ``_attr`` (an object of its own class may be read), and private names imported from another module."""
    tree = ast.parse(source)
    owned = _own_private_names(tree) | PUBLIC_UNDERSCORED
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                continue
            if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
                continue
            if node.attr not in owned and (name, node.attr) not in ALLOWED_REACHES:
                found.append(f"{name}:{node.lineno} {ast.unparse(node)}")
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sb3_crowdnav"):
            found += [f"{name}:{node.lineno} imports {a.name} from {node.module}"
                      for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    return found


def test_no_module_reaches_into_another_modules_private_attributes():
    found = [hit for path in _modules() for hit in private_reaches(path.read_text(), str(path.relative_to(PACKAGE)))]
    assert not found, "\n".join(found)


def test_the_private_reach_check_sees_one():
    probe = ("from sb3_crowdnav.imitation.pretrain import _loss\n\n"
             "class A:\n    def f(self, model, other):\n        return self._x, model._last_obs, other._mine, t._replace()\n"
             "    def g(self):\n        self._mine = 1\n")
    assert sorted(private_reaches(probe, "probe.py")) == ["probe.py:1 imports _loss from sb3_crowdnav.imitation.pretrain",
                                                          "probe.py:5 model._last_obs"]


# ---------------------------------------------------------------- no import circle
MODULE_NAMES = {".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__"): p
                for p in _modules()}


def import_graph(modules: dict[str, Path]) -> nx.DiGraph:
    """Module -> module edges of every ``sb3_crowdnav`` import (top level, inside functions, under TYPE_CHECKING);
    ``from package import module`` is an edge to the module. A package's ``__init__`` re-exporting its own modules
    is not a circle with them: edges from a module to a package that contains it are left out."""
    graph = nx.DiGraph()
    for name, path in modules.items():
        graph.add_node(name)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                           for a in node.names]
            else:
                continue
            graph.add_edges_from((name, t) for t in targets if t in modules and t != name
                                 and not name.startswith(t + "."))
    return graph


def test_no_import_circle():
    cycles = list(nx.simple_cycles(import_graph(MODULE_NAMES)))
    assert not cycles, "\n".join(" -> ".join(cycle) for cycle in cycles)


def test_the_circle_check_sees_one(tmp_path):
    (tmp_path / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sb3_crowdnav.b import B\n")
    (tmp_path / "b.py").write_text("def f():\n    from sb3_crowdnav.a import A\n")
    graph = import_graph({"sb3_crowdnav.a": tmp_path / "a.py", "sb3_crowdnav.b": tmp_path / "b.py"})
    assert list(nx.simple_cycles(graph)) in ([["sb3_crowdnav.a", "sb3_crowdnav.b"]], [["sb3_crowdnav.b", "sb3_crowdnav.a"]])


# ---------------------------------------------------------------- one validator module, one grammar reader
VALIDATORS = {"check_int", "check_number", "check_choice", "check_bool", "check_range", "check_probability",
              "check_positive", "check_instance", "check_at_most"}


def _code_strings(tree: ast.AST) -> list[str]:
    """The string constants of a module that are not docstrings."""
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    return [node.value for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings]


def test_the_validators_are_defined_once():
    defined: dict[str, list[str]] = {}
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name.lstrip("_") in VALIDATORS | {"check_positive_int"}:
                defined.setdefault(node.name, []).append(str(path.relative_to(PACKAGE)))
    assert defined == {name: ["sim/validation.py"] for name in VALIDATORS}


def _reads_the_grammar(source: str) -> bool:
    """Whether code (not a docstring) compares text with a grammar prefix or splits it at the colon."""
    tree = ast.parse(source)
    prefixes = any(s.lower().startswith(("pretrained:", "random:")) for s in _code_strings(tree))
    splits = any(isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "partition"
                 and [getattr(a, "value", None) for a in node.args] == [":"] for node in ast.walk(tree))
    return prefixes or splits


def test_the_policy_grammar_is_read_in_one_module():
    """Only policy_spec.py takes a policy spec apart, and crowd_spec.py a crowd spec: the runner and the CLI ask a
    PolicySpec or a CrowdSpec."""
    readers = {str(path.relative_to(PACKAGE)) for path in _modules() if _reads_the_grammar(path.read_text())}
    assert readers == {"evaluation/policy_spec.py", "evaluation/crowd_spec.py"}
    # not vacuous: the form a second parser would take is seen
    assert _reads_the_grammar('def f(s):\n    return s.lower().startswith("pretrained:")\n')
    assert not _reads_the_grammar('def f(s):\n    """pretrained:NAME"""\n    return s\n')
