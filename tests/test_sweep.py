"""``sb3-crowdnav sweep``: grid refusals, the cell states read from the folders, and a tiny real sweep on Ray."""

import json
import re
import textwrap
from pathlib import Path

import pytest

from sb3_crowdnav.cli import main
from sb3_crowdnav.cli.common import UsageError
from sb3_crowdnav.cli.grid import cell_state, cells, eval_argv, load_grid

HYPERPARAMS = Path(__file__).resolve().parents[1] / "zoo_hyperparams" / "ppo.yml"
TINY_APG = ("{imitation_episodes: 2, imitation_epochs: 1, rl_episodes: 2, checkpoint_episodes: 1, eval_episodes: 1, "
            "exploration_episodes: 1, overlap: off, buffer_size: 1000}")
GRID = f"""\
seeds: [0, 1]
methods:
  APG_RL: {{variant: apg_rl, train: {TINY_APG}}}
  PPO: {{hyperparams: {HYPERPARAMS}, algo: ppo, train: {{timesteps: 64}}}}
envs:
  few: {{num_humans: 2}}
evaluate:
  episodes: 2
  columns: {{same: {{}}, more: {{num_humans: 4}}}}
"""
EPISODES = "\n  episodes: 2\n"  # the evaluate section's line (to add a key after it)


def _grid(tmp_path, text=GRID):
    path = tmp_path / "grid.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def _refused(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.parametrize("change, fragment", [
    (("seeds: [0, 1]", "seed: [0, 1]"), "unknown key 'seed'; allowed: seeds, methods, envs, train, evaluate"),
    (("seeds: [0, 1]", "seeds: [0, -1]"), "seeds: expected integers >= 0"),
    (("seeds: [0, 1]", "seeds: [1, 1]"), "a seed is given twice"),
    (("variant: apg_rl", "variant: apg_xl"), "methods.APG_RL.variant: expected one of apg_carl"),
    (("variant: apg_rl", "variant: apg_rl, hyperparams: x.yml"), "give either 'variant'"),
    (("rl_episodes: 2", "rl_episodez: 2"), "methods.APG_RL.train.rl_episodez: not a train option of a grid; allowed:"),
    (("algo: ppo", "algo: sac"), "methods.PPO.algo: expected one of apg_value"),
    (("timesteps: 64", "timesteps: 64, rl_episodes: 3"), "methods.PPO in envs.few: --rl-episodes is not used with "
                                                         "--hyperparams"),
    (("rl_episodes: 2", "rl_episodes: -2"), "methods.APG_RL in envs.few: argument --rl-episodes: expected a positive"),
    (("eval_episodes: 1", "eval_episodes: 0"), "model 'best' needs validation"),
    (("few: {num_humans: 2}", "few: {num_humanz: 2}"), "num_humanz"),
    (("few:", "a/b:"), "the name 'a/b' must be letters"),
    (("episodes: 2", "episodes: 0"), "evaluate.episodes: expected an integer >= 1, got 0"),
    (("more: {num_humans: 4}", "more: {kinematics: legs}"), "methods.APG_RL in envs.few"),
    (("ppo.yml", "nothing.yml"), "methods.PPO.hyperparams: no file"),
    (("variant: apg_rl", "variant: apg_rl, cpus: 0"), "methods.APG_RL.cpus: expected a positive integer"),
    (("variant: apg_rl", "variant: apg_rl, cpus: true"), "methods.APG_RL.cpus: expected a positive integer"),
    (("algo: ppo", "algo: ppo, seeds: [-1]"), "methods.PPO.seeds: expected integers >= 0"),
    ((EPISODES, EPISODES + "  env: 3\n"), "evaluate.env: expected an env id (e.g. CrowdNavWarehouse-v0), got 3"),
    ((EPISODES, EPISODES + "  env: NoSuchEnv-v0\n"), "methods.APG_RL in envs.few: --env: Environment `NoSuchEnv`"),
    ((EPISODES, EPISODES + "  envs: CrowdNav-v0\n"), "evaluate: unknown key 'envs'; allowed: episodes, seed_offset, "
                                                     "columns, allow_env_mismatch, env"),
])
def test_bad_grids_are_refused_before_any_work(tmp_path, capsys, change, fragment):
    path = _grid(tmp_path, GRID.replace(*change))
    out = tmp_path / "out"
    err = _refused(capsys, ["sweep", str(path), "--out", str(out), "--dry-run"])
    assert fragment in err
    assert not out.exists()


def test_cluster_and_local_cpus_are_not_both_given(tmp_path, capsys):
    err = _refused(capsys, ["sweep", str(_grid(tmp_path)), "--out", str(tmp_path / "o"), "--address", "auto",
                            "--num-cpus", "2"])
    assert "--num-cpus" in err


@pytest.mark.parametrize("argv, grid_change, fragment", [
    (["--num-cpus", "1"], ("variant: apg_rl", "variant: apg_rl, cpus: 2"),
     "methods.APG_RL.cpus: each APG_RL cell reserves 2 CPUs, more than the local Ray instance's 1"),
    (["--num-cpus", "2", "--cpus-per-cell", "3"], ("algo: ppo", "algo: ppo, cpus: 1"),
     "--cpus-per-cell: each APG_RL cell reserves 3 CPUs, more than the local Ray instance's 2"),
])
def test_a_cell_larger_than_the_local_instance_is_refused(tmp_path, capsys, argv, grid_change, fragment):
    path = _grid(tmp_path, GRID.replace(*grid_change))
    assert fragment in _refused(capsys, ["sweep", str(path), "--out", str(tmp_path / "o"), *argv])
    assert not (tmp_path / "o").exists()


def test_only_the_selected_cells_need_to_fit_the_local_instance(tmp_path, capsys):
    """--cells without the 2-CPU method's cells runs on 1 CPU (the dry run lists them); with them it is refused."""
    path = _grid(tmp_path, GRID.replace("variant: apg_rl", "variant: apg_rl, cpus: 2"))
    argv = ["sweep", str(path), "--out", str(tmp_path / "o"), "--num-cpus", "1", "--dry-run"]
    assert main([*argv, "--cells", "PPO/*"]) == 0
    assert capsys.readouterr().out.count("todo     PPO/") == 2
    assert "each APG_RL cell reserves 2 CPUs" in _refused(capsys, [*argv, "--cells", "APG_RL/*/seed_0"])


def test_each_cell_reserves_its_methods_cpus(tmp_path, monkeypatch, capsys):
    """run_on_ray asks Ray for a method's ``cpus`` for each of its cells, --cpus-per-cell for the others (a stand-in
    for Ray records the options of every task; the real Ray runs in the slow test below)."""
    from types import ModuleType, SimpleNamespace

    from sb3_crowdnav.cli.sweep import Report, run_on_ray

    asked = []

    class Task:
        def options(self, **options):
            asked.append(options)
            return self

        def remote(self, cell, grid, threads):
            return cell.name

    fake = ModuleType("ray")
    fake.is_initialized = lambda: True  # a Ray started by the caller: used as it is
    fake.remote = lambda function: Task()
    fake.wait = lambda refs, num_returns: (refs[:1], refs[1:])
    fake.get = lambda ref: Report(None, 1.0)
    fake.exceptions = SimpleNamespace(RayError=RuntimeError)
    monkeypatch.setitem(__import__("sys").modules, "ray", fake)
    grid = load_grid(_grid(tmp_path, GRID.replace("algo: ppo", "algo: ppo, cpus: 1")))
    assert run_on_ray(cells(grid, tmp_path / "out"), grid, cpus_per_cell=2, retries=3) == []
    assert asked == [{"num_cpus": 2, "max_retries": 3}] * 2 + [{"num_cpus": 1, "max_retries": 3}] * 2
    assert capsys.readouterr().out.count("done     ") == 4


def test_a_methods_own_seeds_replace_the_grids(tmp_path, capsys):
    path = _grid(tmp_path, GRID.replace("algo: ppo", "algo: ppo, seeds: [3]"))
    assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines() == ["todo     APG_RL/few/seed_0", "todo     APG_RL/few/seed_1",
                                                    "todo     PPO/few/seed_3", "3 todo, 0 partial, 0 done"]


def test_dry_run_lists_the_cells(tmp_path, capsys):
    assert main(["sweep", str(_grid(tmp_path)), "--out", str(tmp_path / "out"), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == ["todo     APG_RL/few/seed_0", "todo     APG_RL/few/seed_1", "todo     PPO/few/seed_0",
                     "todo     PPO/few/seed_1", "4 todo, 0 partial, 0 done"]
    assert not (tmp_path / "out").exists()


def _touch(path, text=""):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_cell_state_follows_the_run_folder(tmp_path):
    """todo -> partial (imitation, a checkpoint, trained) -> done, read from the files alone; other settings refused."""
    grid = load_grid(_grid(tmp_path))
    cell = cells(grid, tmp_path / "out")[0]
    train = cell.folder / "train"
    assert cell_state(cell, grid) == ("todo", "")
    _touch(cell.folder / "cell.json", json.dumps({"cell": cell.name, "train": cell.train_argv()[:-5]}))
    _touch(train / "imitation.zip")
    assert cell_state(cell, grid) == ("partial", "imitation done; resumes with RL")
    _touch(train / "config.json", json.dumps({"rl_episodes": 2}))
    _touch(train / "checkpoint_1.zip")
    _touch(train / "replay_buffer_1.npz")
    assert cell_state(cell, grid) == ("partial", "resumes at RL episode 1 of 2")
    _touch(train / "final.zip")
    _touch(train / "best.zip")
    assert cell_state(cell, grid) == ("partial", "resumes at RL episode 1 of 2")  # not finished: progress.json says
    _touch(train / "progress.json", json.dumps({"episodes": 2, "finished": True}))
    assert cell_state(cell, grid) == ("partial", "trained; to evaluate: same, more")
    for column, humans in (("same", 2), ("more", 4)):
        folder = cell.folder / "eval" / column
        _touch(folder / "episodes.csv")
        meta = {"env": "CrowdNav-v0", "episodes": 2, "seeds": [1_000_000, 1_000_001], "env_kwargs": {"num_humans": humans},
                "policies": {"APG_RL": str(train / "best.zip")}}
        _touch(folder / "meta.json", json.dumps(meta))
        if column == "same":
            assert cell_state(cell, grid) == ("partial", "trained; to evaluate: more")
    assert cell_state(cell, grid) == ("done", "")
    _touch(cell.folder / "eval" / "more" / "meta.json", json.dumps({**meta, "episodes": 3}))  # other episodes: again
    assert cell_state(cell, grid) == ("partial", "trained; to evaluate: more")
    _touch(cell.folder / "eval" / "more" / "meta.json", json.dumps({**meta, "env": "CrowdNavSquare-v0"}))  # other env
    assert cell_state(cell, grid) == ("partial", "trained; to evaluate: more")

    changed = load_grid(_grid(tmp_path, GRID.replace("rl_episodes: 2", "rl_episodes: 3")))
    with pytest.raises(UsageError, match="holds a run started with other settings"):
        cell_state(cells(changed, tmp_path / "out")[0], changed)


def test_a_hyperparams_cell_is_done_when_train_has_written_its_model(tmp_path):
    grid = load_grid(_grid(tmp_path))
    cell = cells(grid, tmp_path / "out")[2]
    assert cell.method.name == "PPO" and cell.model_path.name == "ppo.zip"
    _touch(cell.train_folder / "tb" / "x")
    assert cell_state(cell, grid) == ("partial", "started; training starts over")
    assert cell.train_argv()[cell.train_argv().index("--checkpoint-freq") + 1] == "50000"  # resumable
    _touch(cell.train_folder / "progress.json", json.dumps({"run": {"timesteps": 64}, "timesteps": 32,
                                                            "checkpoint": "ppo_32_steps.zip"}))
    assert cell_state(cell, grid) == ("partial", "resumes at 32 env steps of 64")
    _touch(cell.model_path)
    _touch(cell.train_folder / "config.json", json.dumps({"wall_time_s": 1.0}))
    assert cell_state(cell, grid)[1] == "trained; to evaluate: same, more"
    argv = eval_argv(cell, grid, "more")  # the file's env_kwargs, the grid env's, then the column's
    assert argv[argv.index("--env-kwargs") + 1] == "{'num_humans': 4}" and argv[argv.index("--env") + 1] == "CrowdNav-v0"


def test_evaluate_env_sets_the_env_of_every_column_with_the_columns_kwargs_alone(tmp_path):
    """Without evaluate.env a column evaluates in the cell's training env over its world's kwargs; with it, in that
    env with the column's kwargs alone (a model trained among several crowds is tested in one base env)."""
    text = textwrap.dedent(f"""\
        seeds: [0]
        methods:
          ROBUST: {{variant: apg_robust, train: {TINY_APG}}}
        evaluate:
          episodes: 2
          columns: {{same: {{actions: with_stop}}, more: {{num_humans: 4, actions: with_stop}}}}
        """)
    grid = load_grid(_grid(tmp_path, text.replace("episodes: 2\n", "episodes: 2\n  env: CrowdNav-v0\n")))
    assert grid.eval_env == "CrowdNav-v0"
    cell = cells(grid, tmp_path / "out")[0]
    argv = eval_argv(cell, grid, "more")
    assert argv[argv.index("--env") + 1] == "CrowdNav-v0"
    assert argv[argv.index("--env-kwargs") + 1] == "{'num_humans': 4, 'actions': 'with_stop'}"
    assert main(["sweep", str(tmp_path / "grid.yaml"), "--out", str(tmp_path / "out"), "--dry-run"]) == 0

    training_env = load_grid(_grid(tmp_path, text))
    argv = eval_argv(cells(training_env, tmp_path / "out")[0], training_env, "more")
    assert argv[argv.index("--env") + 1] == "CrowdNavWorlds-v0"  # the variant's own env, its world's kwargs under the column's
    assert argv[argv.index("--env-kwargs") + 1] == "{'worlds': 'robust', 'actions': 'with_stop', 'num_humans': 4}"


@pytest.mark.parametrize("name, cells", [("sweep_paper.yaml", 12), ("sweep_warehouse.yaml", 3 + 3 + 1 + 1)])
def test_the_example_grids_pass_every_check(name, cells, tmp_path, capsys):
    """The grids in examples/ name files that exist and commands that their own checks accept (a renamed hyperparameter
    file or variant, or a column the evaluation env refuses, fails here)."""
    grid = Path(__file__).resolve().parents[1] / "examples" / name
    assert main(["sweep", str(grid), "--out", str(tmp_path / "out"), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"{cells} todo, 0 partial, 0 done"


def test_a_columns_files_are_relative_to_the_grid_file(tmp_path):
    text = GRID.replace("more: {num_humans: 4}", "more: {crowd: replay, crowd_kwargs: {path: data/rec.txt}}").replace(
        "same: {}", "same: {layout: /abs/layout.yaml}")
    grid = load_grid(_grid(tmp_path, text))
    assert grid.columns["more"]["crowd_kwargs"] == {"path": str((tmp_path / "data" / "rec.txt").resolve())}
    assert grid.columns["same"]["layout"] == "/abs/layout.yaml"  # absolute: as given
    warehouse = load_grid(Path(__file__).resolve().parents[1] / "examples" / "sweep_warehouse.yaml")
    argv = eval_argv(cells(warehouse, tmp_path / "out")[0], warehouse, "layout_file")
    layout = str(Path(__file__).resolve().parents[1] / "examples" / "warehouse_layout.yaml")
    assert argv[argv.index("--env") + 1] == "CrowdNavWarehouse-v0"
    assert argv[argv.index("--env-kwargs") + 1] == repr({"layout": layout})


@pytest.mark.slow  # a local Ray instance (~10 s to start) and 4 tiny training runs
def test_a_sweep_on_ray_resumes_killed_cells_and_skips_finished_ones(tmp_path, capsys, monkeypatch):
    """2 methods x 2 seeds on a real local Ray (1 CPU, loopback): every worker that runs an APG_RL cell is killed
    right after imitation; with --retries 0 those cells fail and the sweep exits 1, the rerun resumes them from
    imitation.zip, and a third run finds every cell done."""
    ray = pytest.importorskip("ray", reason="the cluster extra: pip install 'sb3_crowdnav[cluster]' (make slow)")
    monkeypatch.setenv("SB3_CROWDNAV_KILL_AT", "imitation:1")  # inherited by the Ray workers started below
    monkeypatch.setenv("RAY_worker_niceness", "0")  # Ray's nice 15 starves the workers beside other work (15 min, not 3)
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, _node_ip_address="127.0.0.1")
    try:
        grid, out = str(_grid(tmp_path)), tmp_path / "out"
        argv = ["sweep", grid, "--out", str(out), "--reps", "100"]
        assert main([*argv, "--retries", "0"]) == 1
        captured = capsys.readouterr()
        assert "failed   APG_RL/few/seed_0" in captured.out and "done     PPO/few/seed_1" in captured.out
        assert "2 of 4 cells failed: APG_RL/few/seed_0, APG_RL/few/seed_1" in captured.err
        assert (out / "aggregate.md").is_file()  # the finished cells (PPO) are aggregated already

        assert main(argv) == 0
        lines = capsys.readouterr().out.splitlines()
        assert "partial  APG_RL/few/seed_0 (imitation done; resumes with RL)" in lines
        assert "done     PPO/few/seed_0" in lines and "done     APG_RL/few/seed_1" in " ".join(lines)
        log = (out / "cells" / "APG_RL" / "few" / "seed_0" / "cell.log").read_text()
        assert log.count("$ sb3-crowdnav train") == 2 and "done: 2 RL episodes" in log
        table = (out / "aggregate.md").read_text()
        assert "| APG_RL | all | 2 | 4 |" in table and "| APG_RL | PPO | all |" in table
        # every cell's training budget, read from its run: RL env steps and wall time (the resumed APG cells' sum
        # over their segments, from the imitation on)
        for method, seed in (("APG_RL", 0), ("APG_RL", 1), ("PPO", 0), ("PPO", 1)):
            assert re.search(rf"\| {method} \| {seed} \| [1-9][\d,]* \| \d+\.\d \|", table), table

        assert main(argv) == 0
        assert "0 todo, 0 partial, 4 done" in capsys.readouterr().out
    finally:
        ray.shutdown()


def test_cells_selects_what_runs(tmp_path, capsys, monkeypatch):
    """--cells runs only the matching cells (shell-style patterns over METHOD/ENV/seed_S); one matching nothing is
    refused before any work."""
    import sb3_crowdnav.cli.sweep as sweep

    ran = []
    monkeypatch.setattr(sweep, "run_on_ray", lambda todo, *args: ran.extend(c.name for c in todo) or [])
    grid = str(_grid(tmp_path))
    assert main(["sweep", grid, "--out", str(tmp_path / "out"), "--dry-run", "--cells", "PPO/*", "*/seed_1"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "todo     APG_RL/few/seed_1", "todo     PPO/few/seed_0", "todo     PPO/few/seed_1",
        "3 todo, 0 partial, 0 done (--cells: 3 of the grid's 4 cells)"]
    assert main(["sweep", grid, "--out", str(tmp_path / "out"), "--cells", "APG_RL/few/seed_[0]"]) == 0
    assert ran == ["APG_RL/few/seed_0"]
    err = _refused(capsys, ["sweep", grid, "--out", str(tmp_path / "o2"), "--cells", "PPO/*", "LM_RL/*"])
    assert "--cells: 'LM_RL/*' matches none of the grid's cells (APG_RL/few/seed_0, " in err
    assert not (tmp_path / "o2").exists()
