"""Training of learned policies with stable-baselines3: see issue 5."""
