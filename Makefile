# Entry points: `make demo`, `make test` and `make check`. All build .venv from nothing, pinned by
# constraints.txt (torch 2.13.0 CPU lies on this machine's disk; nothing is fetched at run time).
# `make check` is the fast loop (under a minute on 2 cores): ruff and every test not marked
# slow (`pytest -m "not slow"`), in .venv only. `make test` runs everything and also builds
# .venv-rllib for the Ray RLlib tests: Ray 2.60 pins gymnasium 1.2.2 where .venv has 1.4.0,
# so it gets its own environment, pinned by constraints-rllib.txt.
PYTHON ?= python3
PIP_FLAGS := --quiet --disable-pip-version-check
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCHRL_STAMP := $(VENV)/.installed-torchrl
RLLIB_VENV := .venv-rllib
RLLIB_BIN := $(RLLIB_VENV)/bin
RLLIB_STAMP := $(RLLIB_VENV)/.installed
# Each environment runs exactly the tests it has the dependencies for: .venv everything but
# tests/rllib/ (TorchRL included); .venv-rllib tests/rllib/ and, on its gymnasium 1.2.2, the
# environment's own tests.
RLLIB_TESTS := tests/rllib tests/test_fxc_consensus_v0.py tests/test_consensus_env.py tests/test_vec_env.py
# `make check` runs its tests as these two shares, side by side (see check below).
CHECK_SHARDS := check-shard-1 check-shard-2

.PHONY: demo test check $(CHECK_SHARDS) lint format clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt -e ".[test]"
	touch $(STAMP)

# The tests need TorchRL (the native env) and the bench contenders (MPE2, VMAS: fxc speed's tables).
$(TORCHRL_STAMP): $(STAMP)
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt -e ".[test,torchrl,bench]"
	touch $(TORCHRL_STAMP)

$(RLLIB_STAMP): pyproject.toml constraints-rllib.txt
	test -x $(RLLIB_BIN)/python || $(PYTHON) -m venv $(RLLIB_VENV)
	$(RLLIB_BIN)/pip install $(PIP_FLAGS) -c constraints-rllib.txt -e ".[rllib,test]"
	touch $(RLLIB_STAMP)

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/fxc simulate --scenario paper_fig1 --out out

test: $(TORCHRL_STAMP) $(RLLIB_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	MPLBACKEND=Agg $(BIN)/python -m pytest --ignore=tests/rllib
	MPLBACKEND=Agg $(RLLIB_BIN)/python -m pytest $(RLLIB_TESTS)

# The fast loop: the end-to-end tests (whole trainings, solve_ivp sweeps, shipped-policy
# evaluations, wheel builds, big benchmark runs) are marked slow and left to `make test`.
# The rest runs as two pytest processes at once, one per core: `--shard 1/2` and `--shard 2/2`
# (tests/conftest.py) each take every second selected test; their reports print one after the other.
check: $(TORCHRL_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MAKE) --no-print-directory -j2 --output-sync=target $(CHECK_SHARDS)

$(CHECK_SHARDS): check-shard-%:
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -m "not slow" --ignore=tests/rllib --shard $*/2

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) $(RLLIB_VENV) out .pytest_cache .ruff_cache
