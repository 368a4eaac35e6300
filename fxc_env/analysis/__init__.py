"""Whole runs and their pictures: :func:`~fxc_env.analysis.simulation.simulate` and the figures.

Layer 5, above the environments and policies.
"""
