"""Experiments: filter variants, Monte Carlo runs, model validation against JSBSim."""
