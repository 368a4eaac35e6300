"""Tests that need BenchMARL: run by `make test` in .venv-benchmarl (BenchMARL 1.5 needs torchrl < 0.12)."""
