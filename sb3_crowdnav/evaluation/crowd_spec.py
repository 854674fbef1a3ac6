"""The crowd grammar of the command line and the scripts: ``NAME``, ``NAME:key=value,...`` and ``replay:PATH[,...]``.

A crowd spec names a crowd model of :data:`sb3_crowdnav.sim.crowd.CROWD_MODELS` (the env's ``crowd=``) and, after a
colon, its settings (the env's ``crowd_kwargs=``) as ``key=value`` pairs separated by commas. A value is read as a JSON
scalar where it is one (``0.2``, ``15``, ``true``, ``null``), else kept as text. ``replay:PATH`` is short for
``replay:path=PATH`` (so ``replay:eth.txt,frame_rate=15``), and a replay's path stays text. A comma always separates
settings: a path holding one cannot be given here (pass ``crowd_kwargs`` in Python).

This module is the only place that reads a spec, and it checks the syntax only: whether the model is registered and
its settings are valid is the env's to say (:class:`~sb3_crowdnav.sim.config.SceneConfig`), so a spec works with any
model registered later without a change here. :meth:`CrowdSpec.env_kwargs` gives the env's keyword arguments.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_crowdnav.sim.validation import check_instance

GRAMMAR = "NAME (a crowd model, e.g. orca), NAME:key=value[,key=value...] or replay:PATH[,frame_rate=F]"
_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
REPLAY = "replay"  # the model whose first setting may be a bare path


def _scalar(text: str) -> Any:
    """``text`` as a JSON scalar (int, float, bool, None) where it is one, else the text itself."""
    try:
        value = json.loads(text)
    except ValueError:
        return text
    return text if isinstance(value, (list, dict, str)) else value


def _text(value: Any) -> str:
    """A setting's value written back so that :func:`_scalar` reads the same value."""
    return value if isinstance(value, str) else json.dumps(value)


@dataclass(frozen=True)
class CrowdSpec:
    """A parsed crowd spec: the model's name and its settings in the order given.

    :param model: the crowd model's name (the env's ``crowd``), lower-case letters, digits and ``_``
    :param settings: ``(key, value)`` pairs, the env's ``crowd_kwargs``; keys distinct
    """

    model: str
    settings: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        check_instance("model", self.model, str, "a crowd model's name")
        if not _NAME.match(self.model):
            raise ValueError(f"a crowd model's name is lower-case letters, digits and '_', got {self.model!r}")
        keys = [key for key, _ in self.settings]
        if len(set(keys)) != len(keys):
            raise ValueError(f"crowd {self.model!r}: a setting is given twice in {keys}")

    @classmethod
    def parse(cls, text: str | CrowdSpec, name: str = "crowd") -> CrowdSpec:
        """Read ``text`` (the name case-insensitive, surrounding blanks ignored); a ``CrowdSpec`` passes through.

        ``TypeError`` when ``text`` is not a string; ``ValueError`` naming ``name`` (e.g. ``"--crowd"``) and the
        grammar when it does not follow it.
        """
        if isinstance(text, CrowdSpec):
            return text
        check_instance(name, text, str, f"a crowd spec string ({GRAMMAR})")
        head, colon, tail = text.strip().partition(":")
        model = head.strip().lower()
        if not _NAME.match(model):
            raise ValueError(f"{name}: expected {GRAMMAR}, got {text!r}")
        if colon and not tail.strip():
            raise ValueError(f"{name}: nothing after the colon of {text!r}; expected {GRAMMAR}")
        settings: list[tuple[str, Any]] = []
        for i, item in enumerate(tail.split(",") if colon else ()):
            key, equals, value = (part.strip() for part in item.partition("="))
            if not equals and i == 0 and model == REPLAY and key:
                key, value = "path", item.strip()  # replay:PATH
            elif not (equals and _KEY.match(key) and value):
                raise ValueError(f"{name}: expected key=value settings after the colon, got {item.strip()!r} in "
                                 f"{text!r}; the grammar is {GRAMMAR}")
            if any(key == k for k, _ in settings):
                raise ValueError(f"{name}: the setting {key!r} is given twice in {text!r}")
            settings.append((key, value if (model, key) == (REPLAY, "path") else _scalar(value)))
        return cls(model, tuple(settings))

    @property
    def crowd_kwargs(self) -> dict[str, Any]:
        """The model's settings as the env's ``crowd_kwargs``."""
        return dict(self.settings)

    def env_kwargs(self) -> dict[str, Any]:
        """The env's keyword arguments of this crowd: ``crowd`` and, with settings, ``crowd_kwargs``."""
        return {"crowd": self.model, **({"crowd_kwargs": self.crowd_kwargs} if self.settings else {})}

    @property
    def label(self) -> str:
        """A short table label: the spec as text, a replayed recording by its file name rather than its path."""
        items = [Path(str(v)).name if (self.model, k) == (REPLAY, "path") else f"{k}={_text(v)}"
                 for k, v in self.settings]
        return self.model if not items else f"{self.model}:{','.join(items)}"

    def __str__(self) -> str:
        """The spec as text again (``parse(str(spec)) == spec`` for what ``parse`` gives)."""
        items = [f"{k}={_text(v)}" for k, v in self.settings]
        return self.model if not items else f"{self.model}:{','.join(items)}"


__all__ = ["GRAMMAR", "CrowdSpec"]
