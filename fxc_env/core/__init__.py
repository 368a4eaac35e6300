"""The array maths, the bottom layer: graphs and their in-neighbour index arrays, topology families, sampling
schedules, the exact interval maps of the double integrator and of general linear agents, metrics, lower
bounds and the one validation module every front end calls.

Functions on arrays with leading batch dimensions ``(B, N, ...)``, written once for numpy arrays and torch
tensors through the array API (:mod:`.arrays`); nothing here imports Gymnasium, PettingZoo or torch modules
(an import-linter contract in ``pyproject.toml``).
"""
