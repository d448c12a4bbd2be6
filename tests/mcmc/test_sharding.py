"""Chains sharded over devices: same chains as unsharded, padding masked, resume, bad input.

The sharded runs need several devices, so they run in a subprocess with
``--xla_force_host_platform_device_count=4`` (the flag must not leak into other tests); the
subprocess saves every output and the assertions are made here.

Exactness: keys, padding and chain order are exact, so every discrete output (acceptance,
jumps, aux flags, step counters) is identical. Float outputs computed through reductions or
matrix products (log-densities, quaternion norms, Kameleon proposals) may differ in the last
bits: each device compiles the vmapped step for its block of ``C / devices`` chains, and
XLA's CPU code for a reduction or a small dot depends on the batch size (an unsharded run
with a different number of chains shows the same 1-ulp differences for chain 0). Bugs in
the sharding (a wrong key, a shifted chain) change values at O(0.1), far above the
tolerance used here. Resuming on the same mesh shape is bit-identical.
"""

import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.mcmc import sharding

WORKER = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp, numpy as np
    import jaxgrasp as jg

    jg.enable_compilation_cache()
    assert jax.device_count() == 4, jax.devices()
    out = sys.argv[1]
    chain_counts = [int(c) for c in sys.argv[2].split(",")]

    def banana(x):  # analytic, with an aux pytree (float and int leaves)
        logp = -0.5 * jnp.sum(x**2) - 2.0 * (x[1] - x[0] ** 2) ** 2
        return logp, {"norm": jnp.linalg.norm(x), "positive": jnp.int32(x[0] > 0)}

    def gaussian7(g):  # scalar target on grasps
        return -0.5 * jnp.sum((g[:3] / 0.1) ** 2) + 5.0 * g[3]

    sketch = jax.random.normal(jax.random.key(0), (30, 3))
    algs = {
        "kameleon_darting": jg.mcmc.kameleon_darting(
            banana, sketch, sketch[:2], gamma=0.1, nu=0.3, subsample_size=20,
            adapt_steps=6),
        "random_walk": jg.mcmc.random_walk(gaussian7, position_scale=0.05, kappa=50.0),
    }
    arrays = {}

    def save(tag, tree):
        for path, leaf in jax.tree.flatten_with_path(tree)[0]:
            arrays[tag + jax.tree_util.keystr(path)] = np.asarray(leaf)

    for name, alg in algs.items():
        d = 3 if name == "kameleon_darting" else 7
        for chains in chain_counts:
            x0 = 0.3 * jax.random.normal(jax.random.key(chains), (chains, d))
            if d == 7:
                x0 = x0.at[:, 3].add(1.0)
            key = jax.random.key(7)
            tag = f"{name}/{chains}/"
            save(tag + "ref", jg.mcmc.sample(key, alg, x0, 12, return_state=True))
            seen = []
            sharded = jg.mcmc.sample(
                key, alg, x0, 12, return_state=True, devices=4, chunk_size=6,
                callback=lambda t, s, p, i: seen.append(
                    (t, s.position.shape[0], p.shape[1], i.is_accepted.shape[1])))
            assert seen == [(6, chains, chains, chains), (12, chains, chains, chains)], seen
            save(tag + "sharded", sharded)
            if name == "kameleon_darting":
                # stop after 6 steps, save the state to numpy, resume on 2 devices then 4
                pa, ia, sa = jg.mcmc.sample(key, alg, x0, 6, return_state=True, devices=4)
                sa = jax.tree.map(np.asarray, sa)
                pb, ib, sb = jg.mcmc.sample(key, alg, None, 6, initial_state=sa, start_step=6,
                                            return_state=True, devices="all")
                resumed = (np.concatenate([pa, pb]),
                           jax.tree.map(lambda a, b: np.concatenate([a, b]), ia, ib), sb)
                save(tag + "resumed", resumed)
    np.savez(out, **arrays)
    """
)


@pytest.fixture(scope="module")
def runs_for(tmp_path_factory):
    """``runs_for(chains)``: the worker's outputs for that chain count (one subprocess each,
    so the fast suite pays only for the padded case, 6 chains on 4 devices)."""
    cache = {}

    def get(chains):
        if chains not in cache:
            out = tmp_path_factory.mktemp("sharding") / f"runs{chains}.npz"
            # -O0 as in this process (conftest): 12 steps compile far more than they run
            env = {**__import__("os").environ,
                   "XLA_FLAGS": "--xla_force_host_platform_device_count=4"
                                " --xla_backend_optimization_level=0"}
            proc = subprocess.run([sys.executable, "-c", WORKER, str(out), str(chains)],
                                  env=env, capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, proc.stderr[-4000:]
            with np.load(out) as data:
                cache[chains] = dict(data)
        return cache[chains]

    return get


#: 4 chains on 4 devices (no padding) runs in ``make test-all`` only.
CHAINS = [pytest.param(4, marks=pytest.mark.slow), 6]


def _outputs(runs, case, kind):
    prefix = f"{case}/{kind}"
    return {k[len(prefix):]: v for k, v in runs.items() if k.startswith(prefix)}


@pytest.mark.parametrize("method", ["kameleon_darting", "random_walk"])
@pytest.mark.parametrize("chains", CHAINS)
def test_sharded_equals_unsharded(runs_for, method, chains):
    runs = runs_for(chains)
    ref = _outputs(runs, f"{method}/{chains}", "ref")
    got = _outputs(runs, f"{method}/{chains}", "sharded")
    assert ref.keys() == got.keys() and ref
    positions = ref["[0]"]
    assert positions.shape[:2] == (12, chains) and got["[0]"].shape == positions.shape
    # the chains must move, or identical outputs would prove nothing
    assert ref["[1].is_accepted"].mean() > 0.2
    for name, a in ref.items():
        b = got[name]
        assert a.shape == b.shape and a.dtype == b.dtype, name
        if a.dtype.kind != "f":  # decisions, flags, counters
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5, err_msg=name)
    # counts of accepted proposals per chain, and the aux flag of every proposal: exact
    np.testing.assert_array_equal(ref["[1].is_accepted"].sum(0), got["[1].is_accepted"].sum(0))
    if method == "kameleon_darting":
        np.testing.assert_array_equal(ref["[1].aux['positive']"], got["[1].aux['positive']"])
        assert ref["[1].is_jump"].any()  # the darting branch is exercised


@pytest.mark.parametrize("chains", CHAINS)
def test_sharded_resume_is_bit_identical(runs_for, chains):
    """Stop, save the state as numpy, resume on another device count: same as one run."""
    runs = runs_for(chains)
    one = _outputs(runs, f"kameleon_darting/{chains}", "sharded")
    resumed = _outputs(runs, f"kameleon_darting/{chains}", "resumed")
    for name, a in one.items():
        if name.startswith("[2]"):  # final state: shapes C, not the padded count
            assert a.shape[0] == chains, name
        if name.startswith("[0]") or not name.endswith(("logdensity", "acceptance_rate")):
            np.testing.assert_array_equal(a, resumed[name], err_msg=name)


def test_padding_and_mesh_helpers():
    mesh = sharding.chain_mesh(1)
    assert mesh.shape == {"chains": 1} and sharding.chain_mesh(None) is None
    assert sharding.chain_mesh(mesh) is mesh
    assert sharding.padded_size(6, mesh) == 6
    tree = {"x": jnp.arange(6.0).reshape(3, 2), "n": jnp.arange(3)}
    padded = sharding.pad_chains(tree, 5)
    np.testing.assert_array_equal(padded["x"][3:], [[4.0, 5.0], [4.0, 5.0]])
    np.testing.assert_array_equal(padded["n"], [0, 1, 2, 2, 2])
    back = sharding.gather(padded, 3)
    jax.tree.map(np.testing.assert_array_equal, back, tree)
    info = sharding.layout(mesh)
    assert info["num_devices"] == 1 and info["sharded"] and info["process_count"] == 1


@pytest.mark.parametrize(
    "devices, match",
    [("gpu0", "devices must be"), (0, "available"), (99, "available"), (True, "devices must"),
     ([], "devices must"), ("mesh without a chains axis", "chains")],
)
def test_bad_devices(devices, match):
    if devices == "mesh without a chains axis":
        devices = jax.sharding.Mesh(np.array(jax.devices()[:1]), ("x",))
    alg = jg.mcmc.random_walk(lambda g: -jnp.sum(g**2), position_scale=0.1, kappa=20.0)
    with pytest.raises(ValueError, match=match):
        jg.mcmc.sample(jax.random.key(0), alg, jnp.zeros((2, 7)), 3, devices=devices)


MULTIPROCESS_WORKER = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp, numpy as np
    import jaxgrasp as jg
    from jaxgrasp.mcmc import sharding

    process_id, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    assert sharding.initialize_distributed(f"localhost:{port}", 2, process_id) == (process_id, 2)
    assert jax.device_count() == 4 and jax.local_device_count() == 2
    exec(sys.argv[4])  # defines make_alg()
    alg, x0 = make_alg()
    seen = []
    pos, infos = jg.mcmc.sample(jax.random.key(7), alg, x0, 12, devices="all", chunk_size=6,
                                callback=lambda t, s, p, i: seen.append(p.shape))
    assert seen == [(6, 6, 3), (6, 6, 3)], seen  # every process sees all 6 chains
    if sharding.is_main_process():
        np.savez(out, positions=np.asarray(pos), accepted=np.asarray(infos.is_accepted))
    jax.distributed.shutdown()
    """
)

MAKE_ALG = textwrap.dedent(
    """
    def make_alg():
        def banana(x):
            return -0.5 * jnp.sum(x**2) - 2.0 * (x[1] - x[0] ** 2) ** 2
        sketch = jax.random.normal(jax.random.key(0), (30, 3))
        alg = jg.mcmc.kameleon_darting(banana, sketch, sketch[:2], gamma=0.1, nu=0.3,
                                       subsample_size=20, adapt_steps=6)
        return alg, 0.3 * jax.random.normal(jax.random.key(6), (6, 3))
    """
)


@pytest.mark.slow
def test_two_processes_on_localhost(tmp_path):
    """jax.distributed on one machine: 2 processes x 2 CPU devices, 6 chains (padded to 8),
    process 0 writes; same chains as one unsharded process."""
    import os
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = str(s.getsockname()[1])
    out = tmp_path / "mp.npz"
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    procs = [subprocess.Popen([sys.executable, "-c", MULTIPROCESS_WORKER, str(i), port,
                               str(out), MAKE_ALG], env=env, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    errors = [p.communicate(timeout=600)[1] for p in procs]
    assert all(p.returncode == 0 for p in procs), "\n".join(e[-3000:] for e in errors)
    namespace = {"jax": jax, "jnp": jnp, "jg": jg}
    exec(MAKE_ALG, namespace)
    alg, x0 = namespace["make_alg"]()
    pos, infos = jg.mcmc.sample(jax.random.key(7), alg, x0, 12)
    with np.load(out) as got:
        np.testing.assert_array_equal(infos.is_accepted, got["accepted"])
        np.testing.assert_allclose(pos, got["positions"], rtol=1e-5, atol=1e-5)
