"""Classical consensus controllers (baselines) and the deadline benchmark: see issue 4."""
