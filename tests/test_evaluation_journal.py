"""A killed evaluation resumes where it stopped: the episode journal of ``evaluate`` / ``benchmark --out``."""

import json
import math

import pytest

from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation import journal as journals
from sb3_crowdnav.evaluation import runner
from sb3_crowdnav.evaluation.journal import EpisodeJournal, journal_path
from sb3_crowdnav.evaluation.records import EpisodeRecord

EVALUATE = ["evaluate", "--policy", "orca", "--episodes", "6", "--humans", "3", "--no-progress"]


class Killed(BaseException):
    """Stands for the process being killed (the journal keeps what was appended before)."""


def _kill_after(monkeypatch, n):
    """The n + 1-th append kills the run; returns the seeds appended."""
    appended, append = [], EpisodeJournal.append

    def dying(self, record):
        if len(appended) == n:
            raise Killed
        appended.append(record.seed)
        append(self, record)

    monkeypatch.setattr(EpisodeJournal, "append", dying)
    return appended


def _played_seeds(monkeypatch):
    """Records the seeds run_episode plays from now on."""
    played, play = [], runner.run_episode

    def counting(env, policy, seed, *args, **kwargs):
        played.append(seed)
        return play(env, policy, seed, *args, **kwargs)

    monkeypatch.setattr(runner, "run_episode", counting)
    return played


def _whole_and_killed(tmp_path, monkeypatch, kept, argv=EVALUATE):
    """A whole run into tmp_path/whole, then one killed after ``kept`` episodes into tmp_path/cut."""
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main([*argv, "--out", str(whole)]) == 0
    with monkeypatch.context() as m:
        _kill_after(m, kept)
        with pytest.raises(Killed):
            main([*argv, "--out", str(cut)])
    return whole, cut


def test_a_killed_evaluate_plays_only_the_missing_episodes_and_writes_what_a_whole_run_writes(tmp_path, monkeypatch,
                                                                                            capsys):
    whole, cut = _whole_and_killed(tmp_path, monkeypatch, 4)
    journal = cut / "episodes.partial.jsonl"
    assert len(journal.read_text().splitlines()) == 1 + 4 and not (cut / "episodes.csv").exists()
    played = _played_seeds(monkeypatch)
    capsys.readouterr()
    assert main([*EVALUATE, "--out", str(cut)]) == 0
    assert played == [1_000_004, 1_000_005]  # only the two the kill left
    assert "resuming: 4 of the 6 episodes of orca kept from" in capsys.readouterr().err
    assert (cut / "episodes.csv").read_text() == (whole / "episodes.csv").read_text()
    assert (cut / "results.csv").read_text() == (whole / "results.csv").read_text()
    assert not journal.exists()  # removed once the CSV is written


def test_a_line_cut_by_the_kill_is_played_again(tmp_path, monkeypatch):
    whole, cut = _whole_and_killed(tmp_path, monkeypatch, 3)
    journal = cut / "episodes.partial.jsonl"
    text = journal.read_text()
    journal.write_text(text[: len(text) - 25])  # the third record's line cut short
    played = _played_seeds(monkeypatch)
    assert main([*EVALUATE, "--out", str(cut)]) == 0
    assert played == [1_000_002, 1_000_003, 1_000_004, 1_000_005]
    assert (cut / "episodes.csv").read_text() == (whole / "episodes.csv").read_text()


@pytest.mark.parametrize("change", [["--humans", "4"], ["--seed-offset", "7"], ["--policy", "orca-constrained"]])
def test_a_journal_of_other_settings_is_refused_with_one_line(tmp_path, monkeypatch, capsys, change):
    out = tmp_path / "out"
    with monkeypatch.context() as m:
        _kill_after(m, 2)
        with pytest.raises(Killed):
            main([*EVALUATE, "--out", str(out)])
    capsys.readouterr()
    argv = [*EVALUATE, "--out", str(out)]
    flag = argv.index(change[0]) if change[0] in argv else None
    argv = argv[:flag] + change + argv[flag + 2:] if flag is not None else [*argv, *change]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holds the episodes of an evaluation with other settings" in err, err
    assert len((out / "episodes.partial.jsonl").read_text().splitlines()) == 3  # kept as it was


def test_a_crowd_benchmark_keeps_one_journal_per_policy_and_crowd(tmp_path, monkeypatch):
    argv = ["benchmark", "--policy", "orca", "--policy", "random:3", "--crowd", "orca", "social_force",
            "--episodes", "3", "--humans", "2", "--no-progress"]
    pytest.importorskip("jupedsim")
    _whole_and_killed(tmp_path, monkeypatch, 5, argv)  # killed in the second crowd of the first policy, 2 of 3 played
    kept = sorted(p.name for p in (tmp_path / "cut").iterdir())
    assert kept == ["episodes_ORCA_orca.csv", "episodes_ORCA_orca.partial.jsonl",  # finished, kept until the end
                    "episodes_ORCA_social_force.partial.jsonl"]
    played = _played_seeds(monkeypatch)
    assert main([*argv, "--out", str(tmp_path / "cut")]) == 0
    assert len(played) == 1 + 3 + 3  # the kill's last episode, then the other policy's two crowds
    for name in ("crowds.csv", "episodes_ORCA_orca.csv", "episodes_ORCA_social_force.csv",
                 "episodes_Random_social_force.csv"):
        assert (tmp_path / "cut" / name).read_text() == (tmp_path / "whole" / name).read_text(), name
    assert not list((tmp_path / "cut").glob("*.partial.jsonl"))  # removed once every file is written


def test_records_go_through_the_journal_exactly(tmp_path):
    record = EpisodeRecord(seed=5, outcome="collision", steps=3, navigation_time=0.75, path_length=0.1 + 0.2,
                           episode_return=-0.25, discounted_return=-1 / 3, min_separation=math.inf,
                           discomfort_frequency=0.0, comfort_zone_time=0.0, heading_change=math.pi, num_humans=0,
                           collision_with="human")
    journal = EpisodeJournal(journal_path(tmp_path / "episodes.csv"), {"env": "CrowdNav-v0", "kwargs": (1, 2)})
    assert journal.path.name == "episodes.partial.jsonl"
    assert journal.played() == {}
    journal.append(record)
    again = EpisodeJournal(journal.path, {"env": "CrowdNav-v0", "kwargs": [1, 2]})  # a tuple is read back as a list
    assert again.played() == {5: record}  # inf, nan (discomfort_separation) and every float bit
    assert json.loads(journal.path.read_text().splitlines()[0]) == {"settings": {"env": "CrowdNav-v0", "kwargs": [1, 2]}}
    with pytest.raises(ValueError, match=r"other settings \(env\)"):
        EpisodeJournal(journal.path, {"env": "CrowdNavSquare-v0", "kwargs": [1, 2]}).played()
    again.finish()
    assert not journal.path.exists()
    assert journals.SUFFIX == ".partial.jsonl"


def test_run_episodes_plays_the_seeds_it_was_not_given(monkeypatch):
    whole = runner.run_episodes("orca", 4, {"num_humans": 2})
    seen = []
    played = _played_seeds(monkeypatch)
    records = runner.run_episodes("orca", 4, {"num_humans": 2}, played={whole[1].seed: whole[1], 99: whole[0]},
                                  on_record=seen.append)
    assert records == whole
    assert played == [whole[0].seed, whole[2].seed, whole[3].seed]  # a record of a seed not asked for is ignored
    assert [r.seed for r in seen] == played
