"""First-call (compile + run) and second-call times of the grasp trial per batch size.

    .venv/bin/python benchmarks/first_call.py [--object pitcher] [--backend mujoco]
        [--batch 1 2 3 5 8 9 17 33] [--out bench_out/first_call.json]

One process, batch sizes in the order given, no persistent compilation cache (every compile is
cold), poses from ``backend_agreement.agreement_poses``. With batch shapes bucketed
(``jaxgrasp.physics.bucket_size``) only the first B of each bucket pays a compile. Prints and
writes JSON rows ``{batch, first_s, second_s}`` and the count of distinct compiled shapes.
"""

import argparse
import json
import os
import platform
import time
from pathlib import Path


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="pitcher")
    parser.add_argument("--backend", default="mujoco")
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 2, 3, 5, 8, 9, 17, 33])
    parser.add_argument("--out", default="bench_out/first_call.json")
    args = parser.parse_args(argv)

    import backend_agreement as agreement  # a sibling script: sys.path[0] is benchmarks/
    import jax
    import numpy as np

    import jaxgrasp as jg

    obj = jg.objects.load(args.object)
    scene = jg.physics.load_scene(obj)
    engine = jg.physics.mujoco_backend.MujocoEngine(scene)
    poses = np.asarray(agreement.agreement_poses(obj, max(args.batch), placement=engine.place),
                       np.float32)
    trial = jg.physics.make_trial(scene, backend=args.backend)
    rows = []
    for b in args.batch:
        t = time.perf_counter()
        jax.block_until_ready(trial(poses[:b]))
        first = time.perf_counter() - t
        t = time.perf_counter()
        jax.block_until_ready(trial(poses[:b]))
        rows.append({"batch": b, "first_s": round(first, 3),
                     "second_s": round(time.perf_counter() - t, 4)})
        print(json.dumps(rows[-1]), flush=True)
    out = {"meta": {"object": args.object, "backend": args.backend, "jax": jax.__version__,
                    "cpu_count": os.cpu_count(), "machine": platform.machine(),
                    "load_average_1min": os.getloadavg()[0],
                    "note": "no persistent compilation cache; shared machine, under load"},
           "results": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
