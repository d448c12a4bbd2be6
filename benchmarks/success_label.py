"""What should SUCCESS mean? A learning run's distinct successes replayed under stricter protocols.

    .venv/bin/python benchmarks/success_label.py [--object pitcher] [--seed 2] [--out FILE.json]

One default run (Kameleon + GDMC, biased sketch, 8 chains x 1100, MuJoCo C), then its distinct
successful grasps are (1) measured under a robot's pose error (``jg.learn.robustness``, 10 tries
of 3 mm / 3°) and (2) simulated again under stricter ``TrialParams``: a longer hold, a tighter
slip tolerance, a shake. Per protocol: how many successes it keeps and how many of the kept and
the relabelled ones are robust. Also the robust share by quartile of the trial's own numbers
(displacement during the hold, epsilon) and the outcomes of the perturbed tries. JSON + print.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.bench import env
from jaxgrasp.learn.evaluate.robustness import perturbed_poses
from jaxgrasp.physics import Outcome, TrialParams

SHAKE = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))
PROTOCOLS = {
    "default": TrialParams(),
    "hold_steps=150": TrialParams(hold_steps=150),
    "slip_tol=0.005": TrialParams(slip_tol=0.005),
    "shake 1x weight": TrialParams(perturbations=SHAKE),
    "shake 2x weight": TrialParams(perturbations=tuple(tuple(2 * v for v in w) for w in SHAKE)),
}


def quartiles(values, robust) -> list:
    """Robust share per quartile of ``values`` (lowest first)."""
    edges = np.quantile(values, [0.25, 0.5, 0.75])
    bins = np.searchsorted(edges, values, side="right")
    return [round(float(robust[bins == b].mean()), 3) for b in range(4)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--object", default="pitcher")
    p.add_argument("--seed", type=int, default=2)
    p.add_argument("--slip-scale", type=float, default=0.0,
                   help="the learning run's LearnParams.slip_scale (default 0: the paper's)")
    p.add_argument("--out", default="bench_out/success_label.json")
    args = p.parse_args(argv)
    jg.enable_compilation_cache()
    obj = jg.objects.load(args.object)
    sim = jg.learn.Simulator(obj, backend="mujoco", batch_size=8)
    result = jg.learn.active(obj, chains=8, seed=args.seed, trial=sim, progress=False,
                             params=jg.learn.LearnParams(slip_scale=args.slip_scale))
    rob = jg.learn.robustness(result, trial=sim, seed=args.seed)
    g, robust = rob.grasps.astype(np.float32), rob.robust
    rows = {}
    for name, params in PROTOCOLS.items():
        other = jg.learn.Simulator(jg.physics.load_scene(obj, params=params), backend="mujoco")
        held = np.asarray(other.simulate_now(g, merged=True).outcome) == int(Outcome.SUCCESS)
        rows[name] = {"kept": int(held.sum()), "relabelled": int((~held).sum()),
                      "robust_among_kept": float(robust[held].mean()) if held.any() else None,
                      "robust_among_relabelled": (float(robust[~held].mean()) if (~held).any()
                                                  else None)}
        print(f"{name:>16}: keeps {held.sum()} of {len(g)}, robust among kept "
              f"{rows[name]['robust_among_kept']}, among relabelled "
              f"{rows[name]['robust_among_relabelled']}", flush=True)
    own = sim.simulate_now(g, merged=True)
    tries = np.asarray(sim.simulate_now(perturbed_poses(g, rob.noise, args.seed).reshape(-1, 7)
                                        .astype(np.float32), merged=True).outcome)
    report = {"command": " ".join(sys.argv), "device": env.device(), "versions": env.versions(),
              "date": time.strftime("%Y-%m-%d"), "object": args.object, "seed": args.seed,
              "distinct_successful": len(g), "robust_share": rob.robust_share,
              "protocols": rows,
              "robust_share_by_displacement_quartile": quartiles(np.asarray(own.displacement),
                                                                 robust),
              "robust_share_by_epsilon_quartile": quartiles(np.asarray(own.epsilon), robust),
              "perturbed_outcomes": {o.name: float((tries == int(o)).mean()) for o in Outcome}}
    print("robust share by displacement quartile (smallest first):",
          report["robust_share_by_displacement_quartile"])
    print("robust share by epsilon quartile (smallest first):",
          report["robust_share_by_epsilon_quartile"])
    print("outcomes of the perturbed tries:", report["perturbed_outcomes"])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
