"""How similar each transfer object is to its active-set source, and whether the source's demos
hold on it unchanged (MuJoCo C): the measured basis of the paper's transfer story.

    python benchmarks/transfer_similarity.py --seed 0 --out bench_out/transfer_similarity.json
"""

import argparse
import json

import numpy as np

import jaxgrasp as jg
from jaxgrasp.objects import shipped


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="bench_out/transfer_similarity.json")
    args = p.parse_args()
    manifest = shipped.manifest()["objects"]
    demos = {}
    for source in jg.objects.names("active"):
        try:
            demos[source] = jg.learn.demonstrations(source, num=5, seed=args.seed).poses
        except ValueError as err:  # no grasp holds on this object
            print(f"{source}: no demos ({err})", flush=True)
            demos[source] = np.zeros((0, 7), np.float32)
    rows = []
    for target in jg.objects.names("transfer_a") + jg.objects.names("transfer_b"):
        source = jg.objects.similar(target)
        ds, dt = manifest[source]["dimensions"], manifest[target]["dimensions"]
        held = None
        if len(demos[source]):
            trial = jg.physics.make_trial(jg.physics.load_scene(target), backend="mujoco")
            outcome = np.asarray(trial(np.asarray(demos[source], np.float32)).outcome)
            held = {"success": int((outcome == 0).sum()), "of": len(outcome),
                    "outcomes": outcome.tolist()}
        row = {"target": target, "source": source,
               "height": [ds["height"], dt["height"]],
               "diameter": [ds["diameter"], dt["diameter"]],
               "rim_offset": round(0.5 * (dt["diameter"] - ds["diameter"]), 4),
               "wall": [ds["wall"], dt["wall"]],
               "handle": [manifest[source]["kind"] != "plate",  # pitchers and pans have one
                          manifest[target]["kind"] != "plate"],
               "source_demos_holding_on_target": held}
        rows.append(row)
        print(json.dumps(row), flush=True)
    with open(args.out, "w") as f:
        json.dump({"seed": args.seed, "pairs": rows}, f, indent=1)


if __name__ == "__main__":
    main()
