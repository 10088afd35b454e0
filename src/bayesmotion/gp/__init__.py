"""Gaussian-process building blocks with no knowledge of the H-GPDM: kernels, blocked linear
algebra, Gaussian log-densities with their hand-written VJPs, BLAS thread control, the layout of a
batch of points (walkers) for the backend."""
