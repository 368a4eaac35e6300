"""The analytic consensus laws that ``fxc benchmark`` scores against the paper's controller, one module each.

What they share: :mod:`.policy` (reading the local observation and holding an input over an interval),
:mod:`.design` (offline gain design from the graph: Laplacian spectra, the gain tests, the zero-order-hold
map) and :mod:`.motion_signals` (numbers carried by small motions, for the laws that signal). The laws:
:mod:`.linear`, :mod:`.sampled`, :mod:`.finite_time`, :mod:`.prescribed_time`, :mod:`.saturation_aware`,
:mod:`.minimum_time`, :mod:`.leader_follower`, :mod:`.signalling`, :mod:`.graph_agnostic`,
:mod:`.bounded_steer` and :mod:`.filtering`. Each is registered once in :mod:`fxc_env.baselines.registry`.
"""
