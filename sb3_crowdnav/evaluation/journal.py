"""The episodes an evaluation has played so far, kept as they finish, so that a killed evaluation resumes where it
stopped instead of starting over.

``sb3-crowdnav evaluate`` and ``benchmark`` with ``--out DIR`` write each finished episode's record to a journal
beside the episodes CSV it will fill (``DIR/episodes.partial.jsonl`` for ``DIR/episodes.csv``): the run's settings on
the first line, then one record a line. The journal is removed once the CSV is written. The same command again,
with the same settings and ``--out``, plays only the episodes the journal lacks: an episode depends on its seed
alone and JSON keeps every bit of a float, so the CSV and the tables are those of a run that was never interrupted.
A journal of other settings (another env, crowd, seed range, lookahead, or another file behind the same model path,
by its SHA-256) is refused rather than mixed in; a last line cut by the kill is played again.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sb3_crowdnav.evaluation.records import RECORD_FIELDS, EpisodeRecord

SUFFIX = ".partial.jsonl"


def journal_path(episodes_csv: Path) -> Path:
    """The journal of the run that writes ``episodes_csv`` (``episodes.csv`` -> ``episodes.partial.jsonl``)."""
    return episodes_csv.with_name(episodes_csv.stem + SUFFIX)


def plain(value: Any) -> Any:
    """``value`` as JSON gives it back (tuples as lists, paths as text): what the first line is compared in."""
    return json.loads(json.dumps(value, default=str))


class EpisodeJournal:
    """The journal at ``path`` of a run with ``settings`` (a mapping JSON can write).

    :meth:`played` reads what an earlier run of the same settings kept (and starts the file when there is none),
    :meth:`append` adds a finished episode, :meth:`finish` removes the file once the run's results are written.
    """

    def __init__(self, path: str | Path, settings: Mapping[str, Any]) -> None:
        self.path = Path(path)
        self.settings = plain(dict(settings))

    def played(self) -> dict[int, EpisodeRecord]:
        """The records an earlier run kept, by seed; ``ValueError`` naming the file when it was started with other
        settings. The file is written again with the settings and these records (a line cut by a kill dropped)."""
        records: dict[int, EpisodeRecord] = {}
        if self.path.is_file():
            lines = self.path.read_text().splitlines()
            try:
                header = json.loads(lines[0]) if lines else None
            except ValueError:
                header = None
            if header != {"settings": self.settings}:
                had = header.get("settings") if isinstance(header, dict) else None
                had = had if isinstance(had, dict) else {}
                changed = sorted(k for k in {*had, *self.settings} if had.get(k) != self.settings.get(k))
                raise ValueError(f"{self.path} holds the episodes of an evaluation with other settings "
                                 f"({', '.join(changed)}): remove it to start over, or give another --out")
            for line in lines[1:]:
                try:
                    row = json.loads(line)
                    record = EpisodeRecord(**{key: row[key] for key in RECORD_FIELDS if key in row})  # (older: defaults)
                except (ValueError, KeyError, TypeError):
                    break  # the line a kill cut short (it is always the last): played again
                records[record.seed] = record
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("w") as f:
            f.write(json.dumps({"settings": self.settings}) + "\n")
            for record in records.values():
                f.write(_line(record))
        return records

    def append(self, record: EpisodeRecord) -> None:
        """Add a finished episode (written and flushed at once)."""
        with self.path.open("a") as f:
            f.write(_line(record))

    def finish(self) -> None:
        """Remove the journal: the run's results are written."""
        self.path.unlink(missing_ok=True)


def _line(record: EpisodeRecord) -> str:
    return json.dumps(record.to_dict()) + "\n"  # (nan and inf as NaN and Infinity, which json reads back)


__all__ = ["SUFFIX", "EpisodeJournal", "journal_path", "plain"]
