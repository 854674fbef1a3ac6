"""sb3-crowdnav-zoo tuned: a study's best trial written over the file it started from, with the study's budget."""

from __future__ import annotations

import pytest

optuna = pytest.importorskip("optuna")

from sb3_crowdnav.training.hyperparams import load_hyperparams, policy_kwargs_names, prepare, safe_eval  # noqa: E402
from sb3_crowdnav.training.zoo import main as zoo_main  # noqa: E402
from sb3_crowdnav.training.zoo import register, sample_dqn_params  # noqa: E402

BASE = ("# a base file\nCrowdNav-v0:\n  policy: 'ApgPolicy'\n  imitation_episodes: 30\n  n_timesteps: 1000\n"
        "  policy_kwargs: \"dict(features_extractor_kwargs=dict(attention_dim=32))\"\n  gamma: 0.5\n")
COMMAND = ("python -m sb3_crowdnav.training.zoo train --algo dqn --env CrowdNav-v0 -conf base.yml -optimize "
           "--n-trials 6 --n-timesteps 40000 --n-evaluations 2 --eval-episodes 50")


def _study(tmp_path, trials: int):
    register()
    storage = f"sqlite:///{tmp_path / 'tune.db'}"
    study = optuna.create_study(storage=storage, study_name="dqn", direction="maximize",
                                sampler=optuna.samplers.RandomSampler(seed=0))
    study.set_user_attr("command", COMMAND)

    def objective(trial):  # a score from the sampled values, as a trial's mean reward would be
        params = sample_dqn_params(trial, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})
        if trial.number == 1:
            raise optuna.TrialPruned()
        return -abs(params["learning_rate"] - 1e-4) + 0.01 * params["n_steps"]

    study.optimize(objective, n_trials=trials)
    return storage, study


def test_the_best_trial_is_written_over_the_base_file_with_its_budget(tmp_path, capsys):
    from rl_zoo3 import hyperparams_opt

    storage, study = _study(tmp_path, 6)
    (tmp_path / "base.yml").write_text(BASE)
    out = tmp_path / "tuned.yml"
    zoo_main(["tuned", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(tmp_path / "base.yml"),
              "--storage", storage, "--study-name", "dqn", "--out", str(out)])
    assert f"trial #{study.best_trial.number}" in capsys.readouterr().out
    text = " ".join(line[2:] for line in out.read_text().splitlines() if line.startswith("# "))  # (wrapped)
    assert "the best of 5 complete trials of study 'dqn' (1 pruned, 0 failed)" in text
    assert "each trial 40000 env steps, scored on 50 validation episodes" in text and "each of 2 evaluations" in text
    assert f"best trial #{study.best_trial.number}, mean episode reward {study.best_trial.value:.4f}" in text
    assert COMMAND in text
    hp = load_hyperparams(out)
    best = hyperparams_opt.HYPERPARAMS_CONVERTER["dqn"](dict(study.best_trial.params))
    for key in ("learning_rate", "batch_size", "n_steps", "gamma", "exploration_fraction", "target_update_interval"):
        assert hp[key] == best[key], key  # the trial's values, the base's gamma replaced
    assert hp["imitation_episodes"] == 30 and hp["n_timesteps"] == 1000  # the base's other keys kept
    policy_kwargs = safe_eval(hp["policy_kwargs"], policy_kwargs_names())
    assert policy_kwargs["net_arch"] == best["policy_kwargs"]["net_arch"]
    assert policy_kwargs["features_extractor_kwargs"] == {"attention_dim": 32}  # over the base's, as trials ran
    prepare("dqn", hp)  # a file sb3-crowdnav train --hyperparams takes


@pytest.mark.parametrize("change, fragment", [
    (["--study-name", "nope"], "no study 'nope'"),
    (["--algo", "nope"], "rl-zoo3 has no converter for 'nope'"),
    (["-conf", "missing.yml"], "no hyperparameter file"),
    (["--out", "/nonexistent/dir/t.yml"], "its folder does not exist"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, change, fragment):
    storage, _ = _study(tmp_path, 1)
    (tmp_path / "base.yml").write_text(BASE)
    argv = {"--algo": "dqn", "--env": "CrowdNav-v0", "-conf": str(tmp_path / "base.yml"), "--storage": storage,
            "--study-name": "dqn", "--out": str(tmp_path / "t.yml")}
    argv.update(dict(zip(change[::2], change[1::2], strict=True)))
    with pytest.raises(SystemExit) as exc:
        zoo_main(["tuned", *[x for pair in argv.items() for x in pair]])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0]
    assert not (tmp_path / "t.yml").exists()


def test_a_study_without_a_complete_trial_is_refused(tmp_path, capsys):
    register()
    storage = f"sqlite:///{tmp_path / 'tune.db'}"
    optuna.create_study(storage=storage, study_name="empty", direction="maximize")
    (tmp_path / "base.yml").write_text(BASE)
    with pytest.raises(SystemExit) as exc:
        zoo_main(["tuned", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(tmp_path / "base.yml"),
                  "--storage", storage, "--study-name", "empty", "--out", str(tmp_path / "t.yml")])
    assert exc.value.code == 2 and "has no complete trial yet" in capsys.readouterr().err


def test_the_header_states_the_finished_trials_wall_time(tmp_path):
    """Start to end of every complete and pruned trial, summed; a failed trial (marked so when the study resumed,
    hours after its machine stopped) and a running one are not counted."""
    import datetime

    from optuna.distributions import FloatDistribution
    from optuna.trial import FrozenTrial, TrialState

    from sb3_crowdnav.training.tuned import header, study_budget

    study = optuna.create_study(storage=f"sqlite:///{tmp_path / 'tune.db'}", study_name="t", direction="maximize")
    start = datetime.datetime(2026, 12, 4, 4, 0)
    dist = {"learning_rate": FloatDistribution(1e-5, 1e-2, log=True)}
    for number, (state, minutes, value) in enumerate([(TrialState.COMPLETE, 30, 0.5), (TrialState.PRUNED, 42, None),
                                                      (TrialState.FAIL, 15, None), (TrialState.RUNNING, None, None)]):
        end = None if minutes is None else start + datetime.timedelta(minutes=minutes)
        study.add_trial(FrozenTrial(number=number, state=state, value=value, datetime_start=start, datetime_complete=end,
                                    params={"learning_rate": 1e-3}, distributions=dist, user_attrs={}, system_attrs={},
                                    intermediate_values={}, trial_id=number))
    assert study_budget(study)["trial_hours"] == pytest.approx(1.2)
    text = " ".join(line[2:] for line in header("dqn", "CrowdNav-v0", "b.yml", "t", study, []).splitlines())
    assert "the complete and pruned trials' wall time 1.2 h in all" in text


def _journal_study(tmp_path):
    """A study in a journal file (``.log``): trial 0 complete, trial 1 left RUNNING (as a killed tuning process leaves
    it)."""
    register()
    path = str(tmp_path / "tune.log")
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(path))
    study = optuna.create_study(storage=storage, study_name="dqn", direction="maximize",
                                sampler=optuna.samplers.RandomSampler(seed=0))
    study.set_user_attr("command", COMMAND)
    study.optimize(lambda t: sample_dqn_params(t, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})
                   ["learning_rate"], n_trials=1)
    study.ask()
    return path


def test_a_killed_study_resumes_with_its_running_trials_failed(tmp_path, monkeypatch, capsys):
    """--fail-running marks the RUNNING trial FAIL (so --max-total-trials no longer counts it), leaves the complete one,
    and is taken out of the line rl-zoo3 parses."""
    from optuna.trial import TrialState
    from rl_zoo3 import train as zoo_train

    path = _journal_study(tmp_path)
    seen = {}

    def fake_train():
        import sys

        seen["argv"] = list(sys.argv)
        study = optuna.load_study(study_name="dqn", storage=optuna.storages.JournalStorage(
            optuna.storages.journal.JournalFileBackend(path)))
        seen["states"] = [t.state for t in study.trials]

    monkeypatch.setattr(zoo_train, "train", fake_train)
    zoo_main(["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--storage", path, "--study-name", "dqn",
              "--fail-running"])
    assert seen["states"] == [TrialState.COMPLETE, TrialState.FAIL]
    assert "--fail-running" not in seen["argv"] and "-optimize" in seen["argv"]
    assert "trial 1 of study 'dqn' was left running: marked FAIL" in capsys.readouterr().err
    zoo_main(["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", f"--storage={path}", "--study-name", "dqn",
              "--fail-running"])  # nothing left running: nothing changes
    assert seen["states"] == [TrialState.COMPLETE, TrialState.FAIL]
    assert "marked FAIL" not in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "--storage", "x.log", "--study-name", "s", "--fail-running"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--study-name", "s", "--fail-running"],
    ["enjoy", "--algo", "dqn", "--env", "CrowdNav-v0", "--fail-running"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--storage", "nodb://x", "--study-name", "s",
     "--fail-running"],
])
def test_fail_running_outside_a_resumed_study_exits_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        zoo_main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("--fail-running" in err[0] or "--storage 'nodb://x'" in err[0])


def test_tuned_reads_a_journal_file(tmp_path, capsys):
    path = _journal_study(tmp_path)
    (tmp_path / "base.yml").write_text(BASE)
    argv = ["tuned", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(tmp_path / "base.yml"),
            "--study-name", "dqn", "--out", str(tmp_path / "t.yml")]
    zoo_main([*argv, "--storage", path])
    text = (tmp_path / "t.yml").read_text()
    assert "the best of 1 complete trials" in " ".join(line.lstrip("# ") for line in text.splitlines())
    learning_rate = load_hyperparams(str(tmp_path / "t.yml"), "CrowdNav-v0")["learning_rate"]
    best = optuna.load_study(study_name="dqn", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(path))).best_trial.params["learning_rate"]
    assert learning_rate == pytest.approx(best)
    with pytest.raises(SystemExit) as exc:
        zoo_main([*argv, "--storage", str(tmp_path / "missing.log")])
    assert exc.value.code == 2 and "no journal file" in capsys.readouterr().err


def test_tuned_replaces_only_its_envs_entry_and_keeps_the_others(tmp_path, capsys):
    """A file with one entry per env: the study's env entry (and the comments above it) is rewritten, every other
    entry is kept as written, comments included; an env the file lacks is appended."""
    storage, _ = _study(tmp_path, 3)
    other = ("# the warehouse entry, kept\nCrowdNavWarehouse-v0:\n  policy: 'ApgPolicy'\n  # an inner comment\n\n"
             "  gamma: 0.7\n")
    (tmp_path / "base.yml").write_text(BASE + other)
    out = tmp_path / "base.yml"  # over the file the study started from, as the docs run it
    argv = ["tuned", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(out), "--storage", storage,
            "--study-name", "dqn", "--out", str(out)]
    zoo_main(argv)
    text = out.read_text()
    assert text.endswith(other) and "# a base file" not in text  # the tuned entry's old comments replaced
    assert load_hyperparams(out, "CrowdNavWarehouse-v0")["gamma"] == 0.7
    assert load_hyperparams(out, "CrowdNav-v0")["imitation_episodes"] == 30
    zoo_main(argv)  # again: the same file
    assert out.read_text() == text
    (tmp_path / "wh.yml").write_text(other)
    zoo_main([*argv[:-1], str(tmp_path / "wh.yml")])
    assert (tmp_path / "wh.yml").read_text().startswith(other) and "CrowdNav-v0:" in (tmp_path / "wh.yml").read_text()


def test_a_file_trial_runs_the_files_settings_and_is_queued_once(tmp_path, monkeypatch, capsys):
    """--file-trial queues one trial that the sampler gives no values (the file's settings stand), once per study; a
    failed one is queued again; and it is taken out of the line rl-zoo3 parses."""
    from optuna.trial import TrialState
    from rl_zoo3 import train as zoo_train

    from sb3_crowdnav.training.tuned import FILE_TRIAL
    from sb3_crowdnav.training.zoo import _over_policy_kwargs

    path = str(tmp_path / "new" / "tune.log")  # neither the journal nor its folder exists yet
    seen = {}
    monkeypatch.setattr(zoo_train, "train", lambda: seen.setdefault("argv", __import__("sys").argv[:]))
    argv = ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--storage", path, "--study-name", "s",
            "--file-trial"]
    zoo_main(argv)
    assert "--file-trial" not in seen["argv"] and "a trial of the file's own settings queued" in capsys.readouterr().err
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(path))
    study = optuna.load_study(study_name="s", storage=storage)
    trial = study.ask()  # the queued trial comes first
    assert trial.user_attrs.get(FILE_TRIAL) is True
    sampler = lambda t, *rest: sample_dqn_params(t, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})  # noqa: E731
    assert _over_policy_kwargs(sampler, {"n_quantiles": 5}, trial) == {} and trial.params == {}
    zoo_main(argv)  # running: not queued again
    assert "has a trial of the file's own settings already" in capsys.readouterr().err
    assert len(study.get_trials(states=(TrialState.WAITING,))) == 0
    study.tell(trial.number, state=TrialState.FAIL)  # a killed machine's file trial, marked FAIL: queued again
    zoo_main(argv)
    assert len(study.get_trials(states=(TrialState.WAITING,))) == 1
    other = optuna.create_study(direction="maximize").ask()  # a sampled trial is sampled
    assert _over_policy_kwargs(sampler, {}, other)["learning_rate"] > 0


def test_tuned_keeps_the_files_settings_when_its_trial_is_best(tmp_path, capsys):
    from sb3_crowdnav.training.tuned import FILE_TRIAL

    register()
    storage = f"sqlite:///{tmp_path / 'tune.db'}"
    study = optuna.create_study(storage=storage, study_name="dqn", direction="maximize",
                                sampler=optuna.samplers.RandomSampler(seed=0))
    study.set_user_attr("command", COMMAND)
    study.enqueue_trial({}, user_attrs={FILE_TRIAL: True})
    sampled = lambda t: sample_dqn_params(t, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})  # noqa: E731
    study.optimize(lambda t: 1.0 if t.user_attrs.get(FILE_TRIAL) else (sampled(t), 0.5)[1], n_trials=3)
    (tmp_path / "base.yml").write_text(BASE)
    out = tmp_path / "tuned.yml"
    zoo_main(["tuned", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(tmp_path / "base.yml"),
              "--storage", storage, "--study-name", "dqn", "--out", str(out)])
    text = " ".join(line[2:] for line in out.read_text().splitlines() if line.startswith("# "))
    assert "best trial #0, mean episode reward 1.0000: the file's own settings (--file-trial)" in text
    assert load_hyperparams(out) == load_hyperparams(tmp_path / "base.yml")  # the file's values, unchanged


@pytest.mark.parametrize("argv", [
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "--storage", "x.log", "--study-name", "s", "--file-trial"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--storage", "x.log", "--file-trial"],
    ["enjoy", "--algo", "dqn", "--env", "CrowdNav-v0", "--file-trial"],
])
def test_file_trial_outside_a_stored_study_exits_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        zoo_main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--file-trial" in err[0]


def test_the_header_states_the_file_trials_score_when_another_trial_is_best(tmp_path):
    from sb3_crowdnav.training.tuned import FILE_TRIAL, header

    register()
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=0))
    study.enqueue_trial({}, user_attrs={FILE_TRIAL: True})
    sampled = lambda t: sample_dqn_params(t, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})  # noqa: E731
    study.optimize(lambda t: 0.25 if t.user_attrs.get(FILE_TRIAL) else (sampled(t), 0.75)[1], n_trials=2)
    text = " ".join(line[2:] for line in header("dqn", "CrowdNav-v0", "b.yml", "t", study, []).splitlines())
    assert "best trial #1, mean episode reward 0.7500." in text
    assert "The file's own settings (--file-trial, trial #0) scored 0.2500." in text


def test_a_resumed_study_does_not_draw_its_first_samples_again(tmp_path):
    """The sampler of a resumed study is seeded past the trials it holds: a new process (seed 0) would otherwise draw
    trial 0's random values again for the first trial after the resume; the same study state gives the same sampler,
    and a study that does not exist yet is seeded as rl-zoo3 seeds it."""
    from sb3_crowdnav.training.tuned import stored_trial_count
    from sb3_crowdnav.training.zoo import experiment_manager

    path = _journal_study(tmp_path)  # trials 0 (complete) and 1 (running), drawn with RandomSampler(seed=0)
    assert stored_trial_count(path, "dqn") == 2
    assert stored_trial_count(path, "other") == 0 and stored_trial_count(str(tmp_path / "none.log"), "dqn") == 0
    database = _study(tmp_path, 3)[0]  # a database URL (sqlite) as well
    assert stored_trial_count(database, "dqn") == 3 and stored_trial_count(database, "other") == 0
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(path))
    first = optuna.load_study(study_name="dqn", storage=storage).trials[0].params

    def manager(study_name):
        em = object.__new__(experiment_manager())  # (only the attributes the sampler reads)
        em.seed, em.storage, em.study_name, em.n_startup_trials = 0, path, study_name, 3
        return em

    def next_params(study_name):
        em = manager(study_name)
        sampler = em._create_sampler("random")
        assert em.seed == 0  # given back
        study = optuna.create_study(direction="maximize", sampler=sampler)  # a fresh study: only the seed differs
        trial = study.ask()
        sample_dqn_params(trial, 81, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})
        return trial.params

    assert next_params("other") == first  # a new study: seed 0, as rl-zoo3 (and as trial 0 was drawn)
    resumed = next_params("dqn")
    assert resumed != first and resumed == next_params("dqn")


def test_a_trial_past_its_minutes_is_pruned_and_says_so(tmp_path, capsys):
    """--trial-minutes: a real study whose one trial runs past its (tiny) minutes stops at the next step, is PRUNED
    with the minutes recorded, counts for --max-total-trials, and tuned's header says how many were stopped; rl-zoo3's
    own callback is given back after the command."""
    from optuna.trial import TrialState
    from rl_zoo3 import exp_manager

    original = exp_manager.TrialEvalCallback
    (tmp_path / "base.yml").write_text("CrowdNav-v0:\n  policy: 'ApgPolicy'\n  n_timesteps: 3000\n"
                                       "  learning_starts: 0\n  buffer_size: 1000\n")
    path = str(tmp_path / "study.log")
    argv = ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-conf", str(tmp_path / "base.yml"), "-optimize",
            "--max-total-trials", "1", "--n-timesteps", "3000", "--n-evaluations", "1", "--eval-episodes", "2",
            "--sampler", "random", "--pruner", "none", "--storage", path, "--study-name", "s", "-f",
            str(tmp_path / "logs"), "--trial-minutes", "0.002"]
    with pytest.raises(SystemExit) as exc:  # its one trial pruned: no best trial to print
        zoo_main(argv)
    assert exc.value.code == 1 and "'s' has no complete trial yet" in capsys.readouterr().err
    assert exp_manager.TrialEvalCallback is original
    study = optuna.load_study(study_name="s", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(path)))
    (trial,) = study.trials
    assert trial.state == TrialState.PRUNED and trial.user_attrs["pruned_after_minutes"] == 0.002
    assert (trial.datetime_complete - trial.datetime_start).total_seconds() < 60  # not its 3,000 steps
    with pytest.raises(SystemExit):  # the study holds its one trial: nothing more runs
        zoo_main(argv)
    assert len(optuna.load_study(study_name="s", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(path))).trials) == 1
    from sb3_crowdnav.training.tuned import study_budget

    budget = study_budget(study)
    assert (budget["pruned"], budget["timed_out"], budget["trial_minutes"]) == (1, 1, [0.002])


def test_the_header_counts_the_trials_stopped_by_their_minutes(tmp_path):
    from sb3_crowdnav.training.tuned import TRIAL_MINUTES, header

    study = optuna.create_study(direction="maximize")

    def objective(trial):
        if trial.number in (1, 2):  # pruned: trial 2 by the median pruner, trial 1 as the wall-time callback stops one
            if trial.number == 1:
                trial.set_user_attr(TRIAL_MINUTES, 45.0)
            raise optuna.TrialPruned()
        return float(trial.suggest_float("learning_rate", 1e-5, 1e-3))

    study.optimize(objective, n_trials=4)
    text = " ".join(line[2:] for line in header("dqn", "CrowdNav-v0", "base.yml", "dqn", study, []).splitlines())
    assert "(2 pruned, 1 of them still training after 45 min (--trial-minutes), 0 failed)" in text


@pytest.mark.parametrize("argv", [
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--trial-minutes", "0"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--trial-minutes=-5"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--trial-minutes", "nan"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--trial-minutes", "ten"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "-optimize", "--trial-minutes"],
    ["train", "--algo", "dqn", "--env", "CrowdNav-v0", "--trial-minutes", "30"],  # not tuning
    ["enjoy", "--algo", "dqn", "--env", "CrowdNav-v0", "--trial-minutes", "30"],
])
def test_bad_trial_minutes_exit_2_with_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        zoo_main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--trial-minutes" in err[0]
