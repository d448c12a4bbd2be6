"""Chain-steps per second vs number of chains, unsharded and sharded over 1 and 2 devices.

    .venv/bin/python benchmarks/scaling.py [--out bench_out/scaling.json] [--host-devices 2]
        [--chains 8 64 512 4096] [--steps 50] [--physics] [--physics-chains 4 16]

On a CPU-only machine the devices are forced host devices
(``--xla_force_host_platform_device_count``, set here before JAX starts): each device is a
thread of the same process, so 2 devices can use at most the machine's cores (2 on the
project machine, shared with whatever else runs). On GPUs, pass ``--host-devices 0`` and the
real devices are used. Kameleon-darting deadlocks on forced CPU devices once a device's
block is large enough for jaxlib to parallelize its batched QR over the shared intra-op pool
(see ``jaxgrasp.mcmc.sharding``): keep its chain counts small here. For every configuration
the first call (compilation) is timed apart from the steady state (best of 3 calls, outputs
copied to the host in every case).

``--cost-growth`` (instead of the sampler runs): how cost grows with the batch, on one object
(``--object``, default pitcher) with MuJoCo C: the full trial's trials/s vs B
(``--trial-batches``, 1...4096; first call = compile + run timed apart, then the best of
repeated warm calls) and learning proposals/s vs chains (``--learn-chains``, 1...1024:
``jg.learn.active`` with Kameleon + GDMC, ``--learn-iterations`` after ``--learn-burn-in``,
the best of up to 3 further identical calls (as many as fit in ~10 s) so the sampler's
compilation is excluded and a stall of the shared machine is not the figure; demonstrations
computed once beforehand and a random sketch, so the call's trials are the chains' own).
``benchmarks/plot_scaling.py`` draws ``docs/scaling.png`` from that JSON.

Targets: the cheap analytic 7-D grasp density of ``sampler_step.py`` (random walk) and its
lifted R^7 version (Kameleon + darting); with ``--physics`` the MJX trial of a box, traced
into the sampler (``grasp_logdensity(make_trial(scene))``), so the rollouts themselves run
sharded: one chain-step is one physics trial.
"""

import argparse
import os
import sys


def _force_host_devices(argv) -> None:
    # XLA flags must be set before JAX initialises its backend.
    n = 2
    if "--host-devices" in argv:
        n = int(argv[argv.index("--host-devices") + 1])
    if n > 0:
        flag = f"--xla_force_host_platform_device_count={n}"
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flag).strip()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    _force_host_devices(argv)
    import json
    import platform
    import time
    from pathlib import Path

    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxgrasp as jg
    from jaxgrasp import so3
    from jaxgrasp.mcmc import sharding

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_out/scaling.json")
    parser.add_argument("--host-devices", type=int, default=2,
                        help="forced CPU devices (0: use the real devices)")
    parser.add_argument("--chains", type=int, nargs="+", default=[8, 64, 512, 4096])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--samplers", nargs="+", default=["random_walk", "kameleon_darting"])
    parser.add_argument("--physics", action="store_true", help="also the MJX box trial")
    parser.add_argument("--physics-chains", type=int, nargs="+", default=[4, 16])
    parser.add_argument("--physics-steps", type=int, default=3)
    parser.add_argument("--cost-growth", action="store_true",
                        help="only trials/s vs B and proposals/s vs chains (MuJoCo C)")
    parser.add_argument("--object", default="pitcher")
    parser.add_argument("--trial-batches", type=int, nargs="*",
                        default=[1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096])
    parser.add_argument("--learn-chains", type=int, nargs="*",
                        default=[1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024])
    parser.add_argument("--learn-iterations", type=int, default=10)
    parser.add_argument("--learn-burn-in", type=int, default=5)
    parser.add_argument("--sketch-size", type=int, default=100)
    args = parser.parse_args(argv)
    jg.enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR"))

    mu = so3.normalize(jnp.array([0.3, -0.5, 0.2, 0.7]))

    def grasp_logdensity(g):
        return -0.5 * jnp.sum((g[:3] / 0.05) ** 2) + 20.0 * jnp.dot(g[3:], mu)

    k_pos, k_ori = jax.random.split(jax.random.key(0))
    sketch = jnp.concatenate([
        0.05 * jax.random.normal(k_pos, (1000, 3)),
        jax.vmap(lambda k: so3.sample_vmf(k, mu, 20.0))(jax.random.split(k_ori, 1000))], 1)
    lifted = jg.mcmc.lift_quaternion(grasp_logdensity)
    algs = {
        "random_walk": jg.mcmc.random_walk(grasp_logdensity, position_scale=0.01, kappa=200.0),
        "kameleon_darting": jg.mcmc.kameleon_darting(lifted, sketch, sketch[:5]),
    }
    n_dev = jax.device_count()
    layouts = [("unsharded", None)] + [(f"{n}_devices", n) for n in (1, 2, 4, 8) if n <= n_dev]

    def measure(alg, x0, steps, devices):
        def call(seed):
            out = jg.mcmc.sample(jax.random.key(seed), alg, x0, steps, devices=devices)
            return jax.tree.map(np.asarray, out)

        t0 = time.perf_counter()
        call(1)
        first = time.perf_counter() - t0
        best = np.inf
        for rep in range(3):
            t0 = time.perf_counter()
            _, infos = call(2 + rep)
            best = min(best, time.perf_counter() - t0)
        return first - best, best, float(np.mean(infos.is_accepted))

    rows = []
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    def write():
        meta = {
            "jax": jax.__version__, "backend": jax.default_backend(),
            "devices": [str(d) for d in jax.devices()], "host_devices_forced": args.host_devices,
            "cpu_count": os.cpu_count(), "machine": platform.machine(),
            "load_average_1min": os.getloadavg()[0],
            "layout": sharding.layout(sharding.chain_mesh("all")),
            "note": "forced host devices are threads of one process sharing the machine's "
                    "cores (and here other jobs' load)",
            "command": "python benchmarks/scaling.py " + " ".join(argv),
        }
        out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))

    def run(target, name, alg, x0, steps):
        chains = x0.shape[0]
        for layout, devices in layouts:
            compile_s, run_s, acc = measure(alg, x0, steps, devices)
            rows.append({
                "target": target, "sampler": name, "layout": layout,
                "devices": 1 if devices is None else devices, "chains": chains,
                "steps": steps, "compile_s": round(compile_s, 3), "run_s": round(run_s, 4),
                "chain_steps_per_s": round(chains * steps / run_s, 1),
                "acceptance_rate": round(acc, 3),
            })
            write()  # a partial run still leaves its numbers
            r = rows[-1]
            print(f"{target:>8s} {name:>16s} {layout:>10s} C={chains:5d}  "
                  f"{r['chain_steps_per_s']:12.1f} chain-steps/s  compile {compile_s:6.1f} s",
                  flush=True)

    if args.cost_growth:
        cost_growth(args, rows, write)
        return

    for chains in args.chains:
        x0 = sketch[np.arange(chains) % sketch.shape[0]]
        for name in args.samplers:
            run("analytic", name, algs[name], x0, args.steps)

    if args.physics:
        obj = jg.objects.make_box(np.array([0.03, 0.03, 0.05]), 0.2)
        trial = jg.physics.make_trial(jg.physics.load_scene(obj), backend="mjx")
        target = jg.density.grasp_logdensity(trial, floor=1e-3)
        alg = jg.mcmc.random_walk(target, position_scale=0.005, kappa=500.0)
        top = jnp.array([0.0, 0.0, 0.12, 0.0, 1.0, 0.0, 0.0])  # from above, fingers down
        for chains in args.physics_chains:
            x0 = top + jnp.zeros((chains, 7)).at[:, 0].set(jnp.linspace(-0.01, 0.01, chains))
            run("box_mjx", "random_walk", alg, x0, args.physics_steps)

    write()
    print(f"wrote {args.out}")


def cost_growth(args, rows, write):
    """Trials/s vs B (MuJoCo C full trial) and proposals/s vs chains (learning), see the
    module docstring; rows are appended as they are measured (a partial run keeps them)."""
    import time

    import backend_agreement as ba  # sibling scripts: sys.path[0] is benchmarks/
    import end_to_end as e2e
    import jax
    import numpy as np

    import jaxgrasp as jg
    obj = jg.objects.load(args.object)
    trial = jg.physics.make_trial(jg.physics.load_scene(obj), backend="mujoco")
    poses = np.asarray(ba.agreement_poses(obj, max(args.trial_batches, default=1), 0,
                                          placement=trial.engine.place), np.float32)
    for B in args.trial_batches:
        g = poses[:B]
        t0 = time.perf_counter()
        jax.block_until_ready(trial(g))
        first = time.perf_counter() - t0
        best, reps = np.inf, 0
        while reps < 3 and (reps == 0 or best * (reps + 1) < 5.0):
            t0 = time.perf_counter()
            jax.block_until_ready(trial(g))
            best, reps = min(best, time.perf_counter() - t0), reps + 1
        rows.append({"target": "trial_mujoco_full", "object": args.object, "batch": B,
                     "first_call_s": round(first, 3), "run_s": round(best, 4),
                     "trials_per_s": round(B / best, 1)})
        print(rows[-1], flush=True)
        write()
    params = jg.learn.LearnParams(iterations=args.learn_iterations, burn_in=args.learn_burn_in,
                                  sketch_size=args.sketch_size)
    per_chain = args.learn_iterations + args.learn_burn_in
    for chains, sim, learn in e2e.learning_runs(obj, params, args.learn_chains):
        t0 = time.perf_counter()
        learn()
        first = time.perf_counter() - t0
        run, reps = np.inf, 0
        while reps < 3 and (reps == 0 or run * (reps + 1) < 10.0):
            trials0 = sim.num_trials
            t0 = time.perf_counter()
            learn()
            run, reps = min(run, time.perf_counter() - t0), reps + 1
        rows.append({"target": "learn_active_kameleon_darting", "object": args.object,
                     "chains": chains, "proposals": chains * per_chain,
                     "trials_in_call": sim.num_trials - trials0, "calls": reps,
                     "first_call_s": round(first, 2), "run_s": round(run, 3),
                     "proposals_per_s": round(chains * per_chain / run, 1)})
        print(rows[-1], flush=True)
        write()


if __name__ == "__main__":
    main()
