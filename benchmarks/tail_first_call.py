"""What a process pays the first time it calls the C trial's JAX stages at a batch shape, with
the persistent compilation cache: tracing, lowering, then compiling or reading the program.

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/tail_first_call.py \
        [--object pitcher] [--batch 128] [--out bench_out/tail_first_call.json]

Run it twice: the second process reads both programs from the cache (``compile_s`` is then
the read), and its ``trace_s`` is what a cached program would still cost every fresh process
as plain ``jax.jit``; ``stored_first_call_s`` is the contact stage's first call as the trial
makes it (its traced program read from ``<cache>/exported``, or traced and stored there).
"""

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def _clock(fn):
    t = time.perf_counter()
    out = fn()
    return out, round(time.perf_counter() - t, 3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--out", default="bench_out/tail_first_call.json")
    args = ap.parse_args(argv)

    import jaxgrasp as jg
    from jaxgrasp.physics import contacts, load_scene, make_trial, mujoco_backend

    cache = jg.enable_compilation_cache()
    scene = load_scene(jg.objects.load_any(args.object))
    engine = make_trial(scene, backend="mujoco").engine
    stage, base, _ = mujoco_backend.shared_contacts(scene.gripper, scene.params)
    obj = mujoco_backend.object_args(contacts.shared_consts(base, scene))
    g = np.tile(np.array([[0, 0, 0.1, 1, 0, 0, 0]], np.float32), (args.batch, 1))
    raw = engine.start(g)["raw"]
    early = {**{k: raw[k] for k in mujoco_backend.EARLY_KEYS}, "closed": raw["miss"]}
    _, stored_s = _clock(lambda: jax.block_until_ready(stage(obj, early)))
    traced, trace_s = _clock(lambda: stage.jitted.trace(obj, early))
    lowered, lower_s = _clock(traced.lower)
    _, compile_s = _clock(lowered.compile)
    found = stage(obj, early)
    shape = (jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
             jnp.float32(scene.obj.max_radius))
    _, epsilon_s = _clock(lambda: jax.block_until_ready(mujoco_backend.object_epsilon(
        *found, *shape, num_contacts=scene.params.num_contacts, chunk=None)))
    report = {"object": args.object, "batch": args.batch, "cache_dir": str(cache),
              "contacts": {"trace_s": trace_s, "lower_s": lower_s, "compile_s": compile_s},
              "stored_first_call_s": stored_s, "epsilon_first_call_s": epsilon_s}
    print(json.dumps(report))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
