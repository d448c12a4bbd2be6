"""End to end: a learning run's proposals/s over the bare trial's trials/s on the same grasps
(how much of the bare trial's speed a learning run keeps).

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/end_to_end.py \
        [--object pitcher] [--chains 64 256] [--iterations 40] [--repeats 3] \
        [--out bench_out/end_to_end.json]

For each chain count C, in one process: ``jg.learn.active`` (Kameleon + GDMC, the default
``LearnParams``, a random sketch and demonstrations computed once beforehand, so every trial
of the call is a chain's own proposal) is run once to compile, then timed ``--repeats`` times
(best); the bare trial (the same :class:`~jaxgrasp.learn.Simulator`, host call, batch C) is
timed on exactly the proposals that run made, step by step, ``--repeats`` times (best),
interleaved with the learning runs so a shared machine's load hits both alike. ``ratio`` is
proposals/s over trials/s: 1 means the learning loop adds nothing to its physics.
"""

import argparse
import json
import platform
import time
from pathlib import Path


def learning_runs(obj, params, chain_counts):
    """``(chains, Simulator, learn)`` per chain count: ``learn()`` is ``jg.learn.active``
    (Kameleon + GDMC) on that simulator with a random sketch (no physics) and demonstrations
    made once beforehand, so every trial of a call is a chain's own proposal."""
    import functools

    import jaxgrasp as jg

    demos = None
    for chains in chain_counts:
        sim = jg.learn.Simulator(obj, backend="mujoco", batch_size=chains)
        if demos is None:  # once: the learning loop is what is timed, not the demo search
            demos = jg.learn.demonstrations(obj, num=params.num_demos, seed=0, trial=sim,
                                            params=params)
        yield chains, sim, functools.partial(
            jg.learn.active, obj, chains=chains, seed=0, params=params, trial=sim,
            sketch="random", demos=demos, progress=False)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--chains", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--iterations", type=int, default=40)
    ap.add_argument("--burn-in", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="bench_out/end_to_end.json")
    args = ap.parse_args(argv)

    import jax
    import numpy as np

    import jaxgrasp as jg

    jg.enable_compilation_cache()
    obj = jg.objects.load(args.object)
    params = jg.learn.LearnParams(iterations=args.iterations, burn_in=args.burn_in)
    steps = args.iterations + args.burn_in
    rows = []
    for chains, sim, learn in learning_runs(obj, params, args.chains):
        t0 = time.perf_counter()
        result = learn()
        first = time.perf_counter() - t0
        proposals = np.asarray(result.proposals, np.float32)  # (steps, chains, 7)
        sim(proposals[0])  # warm

        def bare(sim=sim, proposals=proposals):
            for step in proposals:
                jax.block_until_ready(sim(step))

        best = {"learn_s": np.inf, "trial_s": np.inf}
        for _ in range(args.repeats):
            for name, fn in (("learn_s", learn), ("trial_s", bare)):
                t0 = time.perf_counter()
                fn()
                best[name] = min(best[name], time.perf_counter() - t0)
        n = chains * steps
        counts = result.counts.sum(axis=0)
        row = {"object": args.object, "chains": chains, "steps": steps, "proposals": n,
               "success_slipped_collision_miss": [int(c) for c in counts],
               "first_learn_s": round(first, 2), "learn_s": round(best["learn_s"], 3),
               "trial_s": round(best["trial_s"], 3),
               "proposals_per_s": round(n / best["learn_s"], 1),
               "trials_per_s": round(n / best["trial_s"], 1),
               "ratio": round(best["trial_s"] / best["learn_s"], 3)}
        rows.append(row)
        print(json.dumps(row), flush=True)
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"machine": platform.processor() or platform.machine(),
                                   "jax": jax.__version__, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
