"""NUTS (numpyro) on the same potential as emcee: the cross-check sampler."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.inference.posterior import Posterior
from bayesmotion.inference.target import start_points


def run_nuts(target, centre, n_steps, burn, thin, seed, progress, n_chains, init, ball):
    from numpyro.infer import MCMC, NUTS

    warm = n_steps if burn is None else burn
    kernel = NUTS(potential_fn=lambda x: -target._logp(x))
    mcmc = MCMC(kernel, num_warmup=warm, num_samples=n_steps, num_chains=n_chains,
                thinning=thin or 1, progress_bar=progress, chain_method="sequential")
    rng = np.random.default_rng(seed)
    init = jnp.asarray(start_points(target, centre, n_chains, init, ball, rng))
    t0 = time.perf_counter()
    mcmc.run(jax.random.PRNGKey(seed), init_params=init, extra_fields=("accept_prob",
                                                                        "potential_energy"))
    seconds = time.perf_counter() - t0
    x = np.asarray(mcmc.get_samples(group_by_chain=True))
    ex = mcmc.get_extra_fields(group_by_chain=True)
    return Posterior(target.model, target, x, -np.asarray(ex["potential_energy"]),
                     np.asarray(ex["accept_prob"]).mean(1), "nuts",
                     {"burn": warm, "thin": thin or 1, "seconds": seconds, "n_steps": n_steps,
                      "n_chains": n_chains})
