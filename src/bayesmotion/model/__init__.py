"""The hierarchical GPDM of Taubert et al. (2012): specification (:class:`~.spec.HGPDM`),
parameters and priors, layers, the log-posterior (eq. 12), MAP fit, conditionals, top-down
generation, the fitted model and its files."""
