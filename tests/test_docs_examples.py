"""Every code block of the README and the quickstart runs (no example that has rotted)."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETUP = ("pip ", "make ")  # installation commands: what these tests run in already


def _blocks(path: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", path.read_text(), flags=re.DOTALL)


def _commands(text: str) -> list[str]:
    """The shell commands of a bash block (continuation lines joined, comments dropped)."""
    joined = re.sub(r"\\\n\s*", " ", text)
    lines = [line.split("  #")[0].split(" # ")[0].strip() for line in joined.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


PAGES = [ROOT / "README.md", ROOT / "docs" / "quickstart.md"]
PYTHON = [(page.name, i, code) for page in PAGES for i, code in enumerate(_blocks(page, "python"))]
SHELL = [(page.name, command) for page in PAGES for block in _blocks(page, "bash") for command in _commands(block)
         if not command.startswith(SETUP)]


def test_the_pages_have_code():
    assert len(PYTHON) >= 2 and len(SHELL) >= 5


# the Python blocks train a model (the quickstart's is the README's snippet again), and the train, benchmark and the
# quickstart's evaluate commands run for 20-40 s each: `make slow` runs them; the default run keeps the README's
# other commands (evaluate, render, ...), which load the shipped models through the same CLI
SLOW_COMMANDS = {("README.md", "train"), ("quickstart.md", "train"), ("README.md", "benchmark"),
                 ("quickstart.md", "evaluate")}
PYTHON_PARAMS = [pytest.param(p, i, code, marks=pytest.mark.slow, id=f"{p}-python-{i}") for p, i, code in PYTHON]
SHELL_PARAMS = [pytest.param(p, c, marks=pytest.mark.slow if (p, c.split()[1]) in SLOW_COMMANDS else (),
                             id=f"{p}-{c.split()[1]}") for p, c in SHELL]


@pytest.mark.parametrize(("page", "index", "code"), PYTHON_PARAMS)
def test_python_blocks_run(tmp_path, page, index, code):
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "imitation: ORCA-robot episodes, 0/100" in result.stdout  # progress from the start


@pytest.mark.parametrize(("page", "command"), SHELL_PARAMS)
def test_shell_commands_run(tmp_path, page, command):
    argv = shlex.split(command)
    assert argv[0] == "sb3-crowdnav", f"{page}: only sb3-crowdnav commands are shown, got {command!r}"
    result = subprocess.run([sys.executable, "-m", "sb3_crowdnav.cli", *argv[1:]], cwd=tmp_path, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]


def test_the_readme_counts_the_shipped_models_and_every_weights_file_is_listed():
    from sb3_crowdnav.models import PRETRAINED, PRETRAINED_SHA256, WEIGHTS_DIR

    words = {8: "eight", 9: "nine", 10: "ten", 11: "eleven", 12: "twelve", 13: "thirteen", 14: "fourteen"}
    assert f"| {words[len(PRETRAINED)]} trained models in the package" in (ROOT / "README.md").read_text()
    assert {p.stem for p in WEIGHTS_DIR.glob("*.zip")} == set(PRETRAINED) == set(PRETRAINED_SHA256)
