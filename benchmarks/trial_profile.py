"""Where a MuJoCo C grasp trial's time goes: physics vs contacts vs epsilon.

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/trial_profile.py \
        [--object pitcher] [--batch 16 64 256] [--repeats 15]

For each B (the first B of ``backend_agreement.agreement_poses``, as benchmarks/throughput.py)
times, best of ``--repeats`` rounds (one call of each per round, interleaved, so a shared
machine's drifting load hits all alike), in one process: the C engine's host call
(physics), the jitted contacts + outcome stage (``rules.trial_results``, compiled with the C
trial's ``contact_options``, which the trial gives its contacts only; on older checkouts
``vmap(rules.trial_result)``) on the engine's output, the jitted epsilon stage
(``protocol.with_epsilon`` on that result) and the whole trial, and counts the graspable
trials (those that need an epsilon). ``ratio`` is full trials/s over physics trials/s. Runs
on an older checkout too (``PYTHONPATH=<checkout>``).
"""

import argparse
import inspect
import json
import time
from functools import partial

import numpy as np


def _best_interleaved(fns, repeats):
    """Best time of each function over ``repeats`` rounds, one call of each per round (on a
    shared machine the load drifts; interleaving exposes every function to the same drift)."""
    import jax

    for fn in fns.values():
        jax.block_until_ready(fn())
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(fn())
            best[name] = min(best[name], time.perf_counter() - t)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--batch", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--epsilon-chunk", type=int, nargs="*", default=[],
                    help="also time the epsilon stage, and the whole trial (full_chunkC_s, "
                         "ratio_chunkC), with epsilon in vmapped chunks of these sizes")
    args = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp
    from throughput import _load_agreement

    import jaxgrasp as jg
    from jaxgrasp.physics import load_scene, make_trial, rules
    from jaxgrasp.physics.contacts import contact_consts
    from jaxgrasp.physics.protocol import Outcome, epsilon_fn, with_epsilon

    jg.enable_compilation_cache()
    obj = jg.objects.make_box() if args.object == "box" else jg.objects.load(args.object)
    scene = load_scene(obj)
    trial = make_trial(scene, backend="mujoco")
    engine = trial.engine
    poses = _load_agreement().agreement_poses(obj, max(args.batch), args.seed,
                                              placement=engine.place)
    cc = contact_consts(scene)
    consts = (jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
              jnp.float32(scene.obj.max_radius))
    if "num_contacts" in inspect.signature(epsilon_fn).parameters:
        eps = epsilon_fn(*consts, scene.params.num_contacts)
    else:  # an older checkout: one setting for every contact count
        eps = epsilon_fn(*consts)

    from jaxgrasp.physics import mujoco_backend

    # The compiler options the C trial's contacts stage has (no YNNPACK; older: none).
    options = getattr(mujoco_backend, "contact_options", lambda: None)()

    @partial(jax.jit, compiler_options=options)
    def contacts(cc, raw):
        if hasattr(rules, "trial_results"):  # contacts only where they count
            return rules.trial_results(raw, cc, scene.params, scene.ids, renormalize=True)
        return jax.vmap(lambda r: rules.trial_result(r, cc, scene.params, scene.ids,
                                                     renormalize=True))(raw)

    @jax.jit
    def epsilon_stage(res):
        return with_epsilon(res, eps)

    chunked = {c: mujoco_backend.make_mujoco_trial(scene, epsilon_chunk=c)
               for c in args.epsilon_chunk}
    for b in args.batch:
        g = poses[:b]
        raw = engine(g)
        raw_j = jax.tree.map(jnp.asarray, raw)
        res = contacts(cc, raw_j)
        need = np.isin(np.asarray(res.outcome), [Outcome.SUCCESS, Outcome.SLIPPED])
        row = {"B": b, "graspable": int(need.sum()),
               "rolled_out": int((~np.asarray(raw["collision"])).sum())}
        fns = {"physics_s": lambda g=g: engine(g)["max_disp"],
               "contacts_s": lambda r=raw_j: contacts(cc, r),
               "epsilon_s": lambda r=res: epsilon_stage(r),
               "full_s": lambda g=g: trial(g)}
        if hasattr(trial, "host"):  # the host pipeline alone, as jg.learn.Simulator calls it
            fns["host_full_s"] = lambda g=g: trial.host(g)
        for c in args.epsilon_chunk:
            f = jax.jit(lambda res, c=c: with_epsilon(res, eps, chunk=c))
            fns[f"epsilon_chunk{c}_s"] = lambda f=f, r=res: f(r)
            fns[f"full_chunk{c}_s"] = lambda t=chunked[c], g=g: t(g)
        row.update(_best_interleaved(fns, args.repeats))
        row["rest_s"] = row["full_s"] - row["physics_s"] - row["contacts_s"] - row["epsilon_s"]
        row["physics_trials_per_s"] = b / row["physics_s"]
        row["full_trials_per_s"] = b / row["full_s"]
        row["ratio"] = row["physics_s"] / row["full_s"]
        for c in args.epsilon_chunk:
            row[f"ratio_chunk{c}"] = row["physics_s"] / row[f"full_chunk{c}_s"]
        if "host_full_s" in row:
            row["host_ratio"] = row["physics_s"] / row["host_full_s"]
        print(json.dumps({k: round(v, 4) if isinstance(v, float) else v
                          for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
