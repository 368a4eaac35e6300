"""How good a trained policy is: scores over seeds, their statistics, and the leaderboard.

* :mod:`.evaluate`: ``fxc evaluate``, a policy file scored on a task's schedule by the benchmark harness;
* :mod:`.seeds`: ``fxc train --seeds``, one run per training seed;
* :mod:`.seed_evaluation` and :mod:`.seed_scores`: the ``(R, S)`` matrix of deadline errors over R training
  seeds and S evaluation states, and its table;
* :mod:`.statistics`: median, interquartile mean and stratified-bootstrap 95 % intervals over training seeds;
* :mod:`.leaderboard`, :mod:`.leaderboard_runs`, :mod:`.leaderboard_files`: ``fxc leaderboard``, every
  algorithm on every task at the shipped budget, its runs and its result files.
"""
