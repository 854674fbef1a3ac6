"""Shared test set-up: one torch thread (two are many times slower on small shared CPUs), headless matplotlib."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture(autouse=True, scope="session")
def _sb3_log_folder(tmp_path_factory):
    """SB3 makes a folder for every logger it configures without one (``SB3-<date>`` under the system's temporary
    folder, unless ``SB3_LOGDIR`` names one): the session's go to one folder of pytest's, which pytest cleans up."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
        yield
