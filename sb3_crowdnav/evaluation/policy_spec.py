"""The policy grammar shared by the runner and the command line: ``orca``, ``orca-constrained``,
``random[:SEED]``, ``pretrained:NAME`` or the path of a saved model.

A spec is text so that it can be typed on the command line and sent to worker processes; this module is
the only place that reads it. :meth:`PolicySpec.parse` checks the syntax only (no file is opened, no
model loaded): the runner and the CLI then resolve each kind in their own way (the CLI checks a file
without unpickling it, the runner loads it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from sb3_crowdnav.sim.validation import check_choice, check_instance

PolicyKind = Literal["orca", "orca-constrained", "random", "pretrained", "file"]
KINDS: tuple[str, ...] = ("orca", "orca-constrained", "random", "pretrained", "file")
GRAMMAR = "orca, orca-constrained, random[:SEED], pretrained:NAME, a saved model .zip or an exported graph .onnx"
_LABELS = {"orca": "ORCA", "orca-constrained": "ORCA-constrained", "random": "Random"}


@dataclass(frozen=True)
class PolicySpec:
    """A parsed policy spec: its ``kind`` and the ``argument`` after the colon (or the file's path).

    :param kind: ``"orca"``, ``"orca-constrained"``, ``"random"``, ``"pretrained"`` or ``"file"``
    :param argument: the seed of ``random:SEED`` (digits; None for plain ``random``), the NAME of
        ``pretrained:NAME``, the path of a ``file``; None for ORCA
    """

    kind: PolicyKind
    argument: str | None = None

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, KINDS)
        check_instance("argument", self.argument, (str, type(None)), "a str or None")
        needs_argument = self.kind in ("pretrained", "file")
        if needs_argument and not self.argument:
            raise ValueError(f"a {self.kind} policy spec needs an argument (a name or a path), got {self.argument!r}")
        if self.kind in ("orca", "orca-constrained") and self.argument is not None:
            raise ValueError(f"an {self.kind} policy spec takes no argument, got {self.argument!r}")
        if self.kind == "random" and self.argument is not None and not self.argument.isdigit():
            raise ValueError(f"the seed of a random policy spec is an int >= 0 written in digits, got {self.argument!r}")

    @classmethod
    def parse(cls, text: str | Path | PolicySpec, name: str = "policy") -> PolicySpec:
        """Read ``text`` (case-insensitive keywords, surrounding blanks ignored); a ``PolicySpec`` passes through.

        ``TypeError`` when ``text`` is not a string or a path; ``ValueError`` naming ``name`` (e.g. ``"--policy"``)
        and the grammar when it does not follow it.
        """
        if isinstance(text, PolicySpec):
            return text
        if isinstance(text, Path):
            return cls("file", str(text))
        if not isinstance(text, str):
            raise TypeError(f"{name} must be a policy spec string ({GRAMMAR}) or an object with predict(), "
                            f"got {type(text).__name__}")
        s = text.strip()
        if not s:
            raise ValueError(f"{name} must be {GRAMMAR}, got {text!r}")
        if s.lower() in ("orca", "orca-constrained"):
            return cls(s.lower())
        head, colon, tail = s.partition(":")
        if head.lower() == "random":
            if colon and not tail.isdigit():  # digits only: int() would also take "-1", "+1" and "1_000"
                raise ValueError(f"{name}: a random policy is 'random' or 'random:SEED' with SEED >= 0, got {text!r}; "
                                 f"the grammar is {GRAMMAR}")
            return cls("random", tail if colon else None)
        if head.lower() == "pretrained":
            if not tail.strip():
                raise ValueError(f"{name}: a shipped model is 'pretrained:NAME', got {text!r}; the grammar is {GRAMMAR}")
            return cls("pretrained", tail.strip())
        return cls("file", s)

    @property
    def seed(self) -> int:
        """The base seed of a random policy (0 for plain ``random``)."""
        return int(self.argument) if self.kind == "random" and self.argument is not None else 0

    @property
    def is_model(self) -> bool:
        """True for a saved model (shipped or a file): it has a network, a world it was trained in, spaces."""
        return self.kind in ("pretrained", "file")

    @property
    def is_onnx(self) -> bool:
        """True for a file ending in ``.onnx``: a decision graph exported by :func:`sb3_crowdnav.deploy.export_onnx`."""
        return self.kind == "file" and Path(str(self.argument)).suffix.lower() == ".onnx"

    def file_sha256(self) -> str | None:
        """The SHA-256 of the file this spec plays (a shipped model's or the file itself), None for ORCA and random:
        what a results folder records, so that a resumed run never mixes the episodes of two files of one name."""
        if not self.is_model:
            return None
        from sb3_crowdnav.models import file_sha256, pretrained_path

        return file_sha256(pretrained_path(str(self.argument)) if self.kind == "pretrained" else str(self.argument))

    @property
    def label(self) -> str:
        """A short table label: ``ORCA``, ``ORCA-constrained``, ``Random``, the shipped name in capitals, the file's stem."""
        if self.kind == "pretrained":
            return str(self.argument).upper()
        if self.kind == "file":
            return Path(str(self.argument)).stem
        return _LABELS[self.kind]

    def __str__(self) -> str:
        """The spec as text again, e.g. for a results file (``parse(str(spec)) == spec`` for what ``parse`` gives)."""
        if self.kind == "file":
            return str(self.argument)
        return self.kind if self.argument is None else f"{self.kind}:{self.argument}"


def is_spec(policy: Any) -> bool:
    """Whether ``policy`` is a spec (text, a path or a :class:`PolicySpec`) rather than an object with ``predict``."""
    return isinstance(policy, (str, Path, PolicySpec))


__all__ = ["GRAMMAR", "PolicySpec", "is_spec"]
