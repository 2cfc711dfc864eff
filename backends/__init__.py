"""Solvers behind asap-dsl, installed as ``asap_dsl.backends``: RL training (stable-baselines3),
the CasADi minimum-time oracle, and baselines."""
