"""Numerical configuration applied when bayesmotion is imported.

GP marginal likelihoods over hundreds of frames need float64 (Cholesky of kernel matrices with
condition numbers ~1e8), so bayesmotion switches JAX to 64-bit, as numpyro's ``enable_x64`` does.
Code that wants float32 elsewhere can switch it back after import; bayesmotion's own functions
cast their inputs to float64 explicitly where it matters.
"""

import jax

jax.config.update("jax_enable_x64", True)
