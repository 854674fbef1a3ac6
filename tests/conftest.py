"""Shared test set-up: one torch thread (two are many times slower on small shared CPUs), headless matplotlib."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import torch

torch.set_num_threads(1)
