# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH ?= torch==2.13.0
# crowd="social_force": JuPedSim without its viewer's dependencies (PySide6 and VTK, ~1.3 GB); deprecated and wrapt are
# what its Python layer imports
JUPEDSIM ?= jupedsim==1.4.2 deprecated==1.3.1 wrapt==2.5.2
STAMP := $(VENV)/.installed

.PHONY: demo test slow lint docs benchmark reproduce clean

$(STAMP): setup.cfg pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch first and pinned: an unpinned torch pulls several GB of CUDA wheels
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[tests,zoo,gif,deploy,results]"
	$(BIN)/pip install -q --no-deps $(JUPEDSIM)
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python examples/demo.py

test: $(STAMP)
	# pytest exits 5 when it collects nothing (with pytest-xdist too): that fails make, as it should; one worker per
	# core (the tests are independent: each writes under its own tmp_path)
	$(BIN)/python -m pytest -q -n auto

docs: $(STAMP)
	$(BIN)/pip install -q -e ".[docs]"
	# warnings are errors: a broken reference or an unreadable figure fails the build
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html

slow: $(STAMP)
	# Ray (the cluster extra, ~250 MB, ~15 s to install) for the sweep's tests; its start-up (~10 s) keeps them slow
	$(BIN)/pip install -q -e ".[cluster]"
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check sb3_crowdnav tests examples benchmarks

benchmark: $(STAMP)
	$(BIN)/python benchmarks/env_speed.py
	$(BIN)/python benchmarks/network_speed.py
	$(BIN)/python benchmarks/lookahead_speed.py
	$(BIN)/python benchmarks/matmul_rate.py

reproduce: $(STAMP)
	$(BIN)/python examples/reproduce.py

clean:
	rm -rf $(VENV) build *.egg-info docs/_build
