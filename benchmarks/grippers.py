"""Demonstrations on one object with every gripper preset (MuJoCo C): how many of 5 are found.

    python benchmarks/grippers.py --object pitcher --seed 0 --out bench_out/grippers.json
"""

import argparse
import json
import time

import numpy as np

import jaxgrasp as jg
from jaxgrasp.physics.gripper import GRIPPERS


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--object", default="pitcher")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="bench_out/grippers.json")
    args = p.parse_args()
    obj = jg.objects.load(args.object)
    rows = {}
    for name, g in GRIPPERS.items():
        t = time.perf_counter()
        scene = jg.physics.load_scene(obj, gripper=g)
        demos = jg.learn.demonstrations(scene, num=5, seed=args.seed,
                                        trial=jg.learn.Simulator(scene, batch_size=8))
        rows[name] = {"demos": len(demos.poses),
                      "epsilon": np.round(np.asarray(demos.results.epsilon), 4).tolist(),
                      "seconds": round(time.perf_counter() - t, 1)}
        print(name, rows[name], flush=True)
    with open(args.out, "w") as f:
        json.dump({"object": args.object, "seed": args.seed, "grippers": rows}, f, indent=1)


if __name__ == "__main__":
    main()
