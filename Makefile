# Entry points: `make demo`, `make test`, `make check` and `make docs`. All build .venv from nothing, pinned by
# constraints.txt (torch 2.13.0 CPU lies on this machine's disk; nothing is fetched at run time).
# `make check` is the fast loop (about a minute and a half on 2 cores): ruff and every test not marked
# slow (`pytest -m "not slow"`), in .venv only. `make test` runs everything and also builds
# .venv-rllib for the Ray RLlib tests: Ray 2.60 pins gymnasium 1.2.2 where .venv has 1.4.0,
# so it gets its own environment, pinned by constraints-rllib.txt. It also builds .venv-benchmarl
# for the BenchMARL task: BenchMARL 1.5 needs torchrl < 0.12 where .venv has 0.14, pinned by
# constraints-benchmarl.txt (`make benchmarl` builds only that environment), with fxc_env's Hydra plugin, so that
# BenchMARL's own `python -m benchmarl.run ... task=fxc/<task>` finds the tasks there.
PYTHON ?= python3
PIP_FLAGS := --quiet --disable-pip-version-check
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCHRL_STAMP := $(VENV)/.installed-torchrl
RLLIB_VENV := .venv-rllib
RLLIB_BIN := $(RLLIB_VENV)/bin
RLLIB_STAMP := $(RLLIB_VENV)/.installed
BENCHMARL_VENV := .venv-benchmarl
BENCHMARL_BIN := $(BENCHMARL_VENV)/bin
BENCHMARL_STAMP := $(BENCHMARL_VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs
# Each environment runs exactly the tests it has the dependencies for: .venv everything but
# tests/rllib/ and tests/benchmarl/ (TorchRL included); .venv-rllib tests/rllib/ and, on its gymnasium 1.2.2, the
# environment's own tests.
RLLIB_TESTS := tests/rllib tests/envs/test_fxc_consensus_v0.py tests/envs/test_parallel_env.py tests/envs/test_vec_env.py
# .venv-benchmarl: tests/benchmarl/ and, on its torchrl 0.11, the TorchRL env's own tests.
BENCHMARL_TESTS := tests/benchmarl tests/envs/test_torch_env.py tests/envs/test_interop.py
# `make check` runs its tests as these two shares, side by side (see check below).
CHECK_SHARDS := check-shard-1 check-shard-2

.PHONY: demo test check docs $(CHECK_SHARDS) benchmarl lint format clean

$(STAMP): pyproject.toml constraints.txt fxc_env/engine/_reference_kernel.c
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt -e ".[test]"
	touch $(STAMP)

# The tests need TorchRL (the native env), the bench contenders (MPE2, VMAS: fxc speed's tables),
# Tianshou (tests/test_clients.py) and marl-eval (tests/training/test_leaderboard_files.py loads and plots the
# shipped marl_eval.json with it): id-marl-eval pins pandas 1.4.4 and pulls neptune and jax, so it goes in
# without its dependencies, beside the few its loader and plots import.
$(TORCHRL_STAMP): $(STAMP)
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt -e ".[test,torchrl,bench,tianshou]"
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt rliable seaborn colorcet colorama
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt --no-deps id-marl-eval
	touch $(TORCHRL_STAMP)

$(RLLIB_STAMP): pyproject.toml constraints-rllib.txt fxc_env/engine/_reference_kernel.c
	test -x $(RLLIB_BIN)/python || $(PYTHON) -m venv $(RLLIB_VENV)
	$(RLLIB_BIN)/pip install $(PIP_FLAGS) -c constraints-rllib.txt -e ".[rllib,test]"
	touch $(RLLIB_STAMP)

$(BENCHMARL_STAMP): pyproject.toml constraints-benchmarl.txt fxc_env/engine/_reference_kernel.c
	test -x $(BENCHMARL_BIN)/python || $(PYTHON) -m venv $(BENCHMARL_VENV)
	$(BENCHMARL_BIN)/pip install $(PIP_FLAGS) -c constraints-benchmarl.txt -e ".[benchmarl,test]"
	$(BENCHMARL_BIN)/python -m fxc_env.envs.benchmarl_run --install-plugin
	touch $(BENCHMARL_STAMP)

benchmarl: $(BENCHMARL_STAMP)

# The documentation site (fxc_env/docs/, Sphinx + MyST) into build/docs/: offline, warnings are errors,
# every unresolved reference too (-n); -E reads every page afresh (the scenario cards read the library,
# which Sphinx does not track). Its API pages import the TorchRL env, so it builds on the test env.
$(DOCS_STAMP): $(TORCHRL_STAMP)
	$(BIN)/pip install $(PIP_FLAGS) -c constraints.txt -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	MPLBACKEND=Agg $(BIN)/sphinx-build -E -W --keep-going -n -q -b html fxc_env/docs build/docs

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/fxc simulate --scenario paper_fig1 --out out

test: $(TORCHRL_STAMP) $(DOCS_STAMP) $(RLLIB_STAMP) $(BENCHMARL_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MAKE) --no-print-directory docs
	MPLBACKEND=Agg $(BIN)/python -m pytest --ignore=tests/rllib --ignore=tests/benchmarl
	MPLBACKEND=Agg $(RLLIB_BIN)/python -m pytest $(RLLIB_TESTS)
	MPLBACKEND=Agg $(BENCHMARL_BIN)/python -m pytest $(BENCHMARL_TESTS)

# The fast loop: the end-to-end tests (whole trainings, solve_ivp sweeps, shipped-policy
# evaluations, wheel builds, big benchmark runs) are marked slow and left to `make test`.
# The rest runs as two pytest processes at once, one per core: `--shard 1/2` and `--shard 2/2`
# (tests/conftest.py) each take every second selected test; their reports print one after the other.
check: $(TORCHRL_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MAKE) --no-print-directory -j2 --output-sync=target $(CHECK_SHARDS)

$(CHECK_SHARDS): check-shard-%:
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -m "not slow" --ignore=tests/rllib --ignore=tests/benchmarl --shard $*/2

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) $(RLLIB_VENV) $(BENCHMARL_VENV) out build .pytest_cache .ruff_cache
