"""Optimisers over one flat parameter vector: SciPy's L-BFGS-B with a jitted value and gradient
(:func:`~bayesmotion.optim.minimize.map_optimize`) and a jitted JAX L-BFGS
(:mod:`~bayesmotion.optim.lbfgs`)."""
