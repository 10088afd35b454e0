"""The posterior over hyperparameters and style vectors: the sampled target, emcee (default)
and NUTS runners, emcee moves, the HDF5 chain file, diagnostics and posterior-predictive
rollouts."""
