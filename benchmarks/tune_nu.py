"""Differentiating through the Kameleon proposal: tune ν and γ by gradient ascent (optax) on
the expected squared jump distance (ESJD) on a banana target, and compare with the fixed ν.

    .venv/bin/python benchmarks/tune_nu.py [--out bench_out/tune_nu.json]

The proposal is reparameterized (``x* = y + γ ξ₁ + ν M_y H ξ₂``) and ``log q`` is
differentiable, so the Monte Carlo objective (Pasarica & Gelman 2010)

    ESJD(ν, γ) = E_{y ~ π, ξ} [ α(y, x*) |x* − y|² ],
    α = min(1, π(x*) q(y | x*) / (π(y) q(x* | y)))

has pathwise gradients with respect to (log ν, log γ) by plain ``jax.grad``. y is drawn from
exact banana samples (in a real problem: the sketch or the chain history), Z is a fixed
subsample of the sketch, σ the median heuristic. The tuned and the fixed (ν = 2.38/√d,
γ = 0.1) samplers are then run as real chains and compared by measured jump distance,
acceptance rate and effective sample size.
"""

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

import jaxgrasp as jg
from jaxgrasp.mcmc import diagnostics
from jaxgrasp.mcmc.kameleon import (
    default_nu,
    kameleon_proposal_logdensity,
    kameleon_proposal_sample,
    median_heuristic,
)

S1, B = 10.0, 0.1  # strongly curved 2-D banana


def banana_logdensity(x):
    return -0.5 * (x[0] / S1) ** 2 - 0.5 * (x[1] + B * (x[0] ** 2 - S1**2)) ** 2


def banana_exact(key, n):
    z = jax.random.normal(key, (n, 2))
    x1 = S1 * z[:, 0]
    return jnp.stack([x1, z[:, 1] - B * (x1**2 - S1**2)], axis=1)


def esjd_objective(log_params, key, ys, Z, sigma):
    """Monte Carlo ESJD at (log ν, log γ) over the batch ``ys``."""
    nu, gamma = jnp.exp(log_params[0]), jnp.exp(log_params[1])

    def one(key, y):
        x = kameleon_proposal_sample(key, y, Z, sigma, gamma, nu)
        log_ratio = (
            banana_logdensity(x)
            - banana_logdensity(y)
            + kameleon_proposal_logdensity(y, x, Z, sigma, gamma, nu)
            - kameleon_proposal_logdensity(x, y, Z, sigma, gamma, nu)
        )
        alpha = jnp.exp(jnp.minimum(log_ratio, 0.0))
        return alpha * jnp.sum((x - y) ** 2)

    return jnp.mean(jax.vmap(one)(jax.random.split(key, ys.shape[0]), ys))


def run_chains(alg, x0, steps, key):
    positions, infos = jg.mcmc.sample(key, alg, x0, steps)
    pos = np.asarray(positions, np.float64)
    jumps = np.sum(np.diff(pos, axis=0) ** 2, axis=-1)
    ess = diagnostics.effective_sample_size(pos)
    return {
        "acceptance_rate": round(float(np.mean(np.asarray(infos.is_accepted))), 4),
        "squared_jump_distance": round(float(jumps.mean()), 4),
        "ess_per_1000_steps_per_chain": [
            round(float(e) / x0.shape[0] / steps * 1000, 2) for e in ess
        ],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_out/tune_nu.json")
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--chains", type=int, default=256)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args(argv)
    jg.enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR"))

    sketch = banana_exact(jax.random.key(0), 1000)
    pool = banana_exact(jax.random.key(1), 20000)  # y ~ π for the objective
    Z = sketch[np.arange(100) * 10]  # the frozen subsample kameleon(adapt_steps=0) uses
    sigma = median_heuristic(sketch)
    nu0, gamma0 = default_nu(2), 0.1

    optimizer = optax.adam(0.05)
    log_params = jnp.log(jnp.array([nu0, gamma0]))
    opt_state = optimizer.init(log_params)

    @jax.jit
    def update(log_params, opt_state, key):
        k_batch, k_prop = jax.random.split(key)
        ys = pool[jax.random.randint(k_batch, (args.batch,), 0, pool.shape[0])]
        value, grad = jax.value_and_grad(esjd_objective)(log_params, k_prop, ys, Z, sigma)
        updates, opt_state = optimizer.update(-grad, opt_state)  # ascent
        return optax.apply_updates(log_params, updates), opt_state, value

    t0 = time.perf_counter()
    trace = []
    for it in range(args.iterations):
        log_params, opt_state, value = update(log_params, opt_state, jax.random.key(100 + it))
        trace.append(float(value))
        if it % 50 == 0 or it == args.iterations - 1:
            nu, gamma = np.exp(np.asarray(log_params))
            print(f"iter {it:4d}  ESJD {float(value):8.3f}  nu {nu:.4f}  gamma {gamma:.4f}")
    tune_s = time.perf_counter() - t0
    nu_t, gamma_t = (float(v) for v in np.exp(np.asarray(log_params)))

    x0 = banana_exact(jax.random.key(2), args.chains)
    results = {}
    for name, nu, gamma in [("fixed", nu0, gamma0), ("tuned", nu_t, gamma_t)]:
        alg = jg.mcmc.kameleon(banana_logdensity, sketch, gamma=gamma, nu=nu, adapt_steps=0)
        results[name] = {
            "nu": nu,
            "gamma": gamma,
            **run_chains(alg, x0, args.steps, jax.random.key(3)),
        }
        print(name, results[name])

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "target": {"banana_s1": S1, "banana_b": B},
        "sigma": sigma,
        "iterations": args.iterations,
        "batch": args.batch,
        "tune_seconds": round(tune_s, 2),
        "objective_first": trace[0],
        "objective_last_mean10": float(np.mean(trace[-10:])),
        "chains": args.chains,
        "steps": args.steps,
        **results,
    }
    out.write_text(json.dumps(payload, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
