"""The house rules of the package: floors with one-way doors, small modules, one owner of the observation schema."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_crowdnav"
# floor of each top-level part of the package; a module may import its own part or a strictly lower floor
FLOORS = {
    "sim": 0, "version": 0,
    "envs": 1, "nn": 1, "serialization": 1,
    "imitation": 2,
    "apg_value": 3,
    "models": 4,
    "": 4.5,  # ``import sb3_crowdnav``: the public API, registers the envs; its __init__ imports up to floor 4
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
