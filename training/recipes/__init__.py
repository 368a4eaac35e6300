"""Recipes that rebuild the shipped policies of ``fxc_env/pretrained/``, one module (or YAML file) each.

Each module runs as ``python -m fxc_env.training.recipes.<name>`` and writes the file it names
(``fxc_env/pretrained/README.md`` gives each command and the numbers it measured):

* :mod:`.rings` and :mod:`.rings_scratch`: per-interval gain schedules for directed rings (``rings.npz``,
  ``rings_scratch.npz``), from the minimum-time law or from scratch;
* :mod:`.agnostic`: one gain schedule for any graph, not told the graph (``agnostic.npz``);
* :mod:`.noise_gains`: gain tables fitted for measurement noise on a directed ring; :mod:`.recurrent_imitation`: the GRU policy
  (``rings_gru.pt``) that imitates the minimum-time law;
* :mod:`.residual_sensitivity`: how much PPO's exploration noise costs on the rings task.

The YAML files here are ``fxc train --hyperparams`` files of the shipped PPO policies
(``rings20_v2.yml``, ``paper_fig1_k50.yml`` ...).
"""
