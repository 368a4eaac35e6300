"""The training back ends, one module each, and :func:`train`, which runs the one ``fxc train --backend`` names.

* :mod:`.sb3_train`: stable-baselines3 PPO and SAC (``--backend sb3``, the default), with the warm start of
  :mod:`.imitation` (the policy first copies an analytic law, eq. 11 by default);
* :mod:`.rllib_train`: Ray RLlib's PPO (``--backend rllib``, the ``rllib`` extra);
* :mod:`.torch_ppo`: a lean PPO loop in torch (``--backend torch``), sharing :mod:`.torch_common` with
  :mod:`.diff_train`, analytic policy gradients through the engine (``--backend diff``);
* :mod:`.checkpoint_checks`: what a checkpoint must hold before ``--resume`` goes on from it;
* :mod:`.dispatch`: :func:`train`, which imports only the chosen back end (the table of back ends is
  :mod:`fxc_env.training.registry`).
"""

from __future__ import annotations

from fxc_env.training.backends.dispatch import train

__all__ = ["train"]
