"""The trial's epsilon on real contact sets: agreement with Qhull and CPU per trial part.

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/epsilon_real_sets.py \
        [--objects pitcher pan ...] [--seeds 3] [--poses 256] [--part 32] [--repeats 2] \
        [--sets benchmarks/data/real_contact_sets.npz] [--out bench_out/epsilon_real_sets.json]
        [--first-seed 0] [--starts S --eigen-starts E]

Real sets: the contacts after closing of every SUCCESS or SLIPPED trial of the MuJoCo C
backend on ``--poses`` agreement poses (``backend_agreement.agreement_poses``) per seed and
object, kept in ``--sets`` (made once, then reused, so that epsilon changes are compared on
the same input). The repository keeps there the 1720 sets of the 9 objects (3 seeds, 256
poses; docs/design.md, "The JAX tail: contacts and epsilon"); delete the file to harvest
anew. Then, per object, epsilon as
the trial computes it (``protocol.epsilon_fn(...).batch``: its starts, lanes and antipode
setting) on parts of ``--part`` rows, every row needed: misses against
``quality.epsilon_qhull`` (off by more than 1 % relative and 1e-4 absolute), the largest
relative error, and the process CPU per part (median of ``--repeats`` calls per part,
summed over the parts). ``--starts`` / ``--eigen-starts`` run the same batched search from
another number of start directions (``protocol.epsilon_fn``'s ``num_starts`` /
``num_eigen_starts``) to weigh accuracy against CPU; ``--first-seed`` harvests other poses
into a new ``--sets`` file (seeds ``first-seed ... first-seed + seeds - 1``).
"""

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np


def harvest(names, seeds, poses, first_seed=0):
    """{object: dict(pts, nrm, msk, mu, com, rad)} of the graspable trials' contacts."""
    import backend_agreement as ba
    import jax

    import jaxgrasp as jg
    from jaxgrasp.physics import Outcome, load_scene, make_trial

    out = {}
    for name in names:
        obj = jg.objects.load(name)
        scene = load_scene(obj)
        trial = make_trial(scene, backend="mujoco")
        got = []
        for seed in range(first_seed, first_seed + seeds):
            g = ba.agreement_poses(obj, poses, seed, placement=trial.engine.place)
            r = jax.device_get(trial(g))
            keep = (r.outcome == Outcome.SUCCESS) | (r.outcome == Outcome.SLIPPED)
            got.append((r.contact_points[keep], r.contact_normals[keep], r.contact_mask[keep]))
        pts, nrm, msk = (np.concatenate(x) for x in zip(*got, strict=True))
        out[name] = dict(pts=pts, nrm=nrm, msk=msk, mu=float(scene.friction),
                         com=np.asarray(obj.com, np.float32), rad=float(obj.max_radius))
    return out


def save_sets(path, sets):
    flat = {f"{name}/{k}": np.asarray(v) for name, d in sets.items() for k, v in d.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **flat)


def load_sets(path):
    sets = {}
    with np.load(path) as f:
        for key in f.files:
            name, k = key.split("/")
            v = f[key]
            sets.setdefault(name, {})[k] = v.item() if v.ndim == 0 else v
    return sets


def measure(d, part, repeats, starts=None, eigen_starts=None):
    """Agreement and CPU of the trial's epsilon on one object's sets (``starts``: its batched
    search from that many start directions, ``eigen_starts`` of them eigen-directions)."""
    import jax
    import jax.numpy as jnp

    from jaxgrasp.physics.protocol import epsilon_fn
    from jaxgrasp.quality import epsilon_qhull

    n = len(d["pts"])
    fn = jax.jit(epsilon_fn(jnp.float32(d["mu"]), jnp.asarray(d["com"], jnp.float32),
                            jnp.float32(d["rad"]), num_starts=starts,
                            num_eigen_starts=eigen_starts).batch)
    eps, cpu = [], 0.0
    for lo in range(0, n, part):
        k = min(part, n - lo)
        pad = [np.zeros((part,) + d[key].shape[1:], d[key].dtype) for key in ("pts", "nrm", "msk")]
        for a, key in zip(pad, ("pts", "nrm", "msk"), strict=True):
            a[:k] = d[key][lo:lo + k]
        need = np.arange(part) < k
        eps.append(np.asarray(fn(*pad, need))[:k])
        times = []
        for _ in range(repeats):
            c0 = time.process_time()
            jax.block_until_ready(fn(*pad, need))
            times.append(time.process_time() - c0)
        cpu += float(np.median(times))
    eps = np.concatenate(eps).astype(float)
    ref = np.array([epsilon_qhull(d["pts"][i], d["nrm"][i], d["msk"][i], d["mu"], d["com"],
                                  d["rad"]) for i in range(n)])
    miss = np.abs(eps - ref) > np.maximum(0.01 * ref, 1e-4)
    pos = ref > 1e-4
    rel = np.abs(eps - ref)[pos] / ref[pos]
    return {"sets": n, "qhull_misses": int(miss.sum()),
            "max_rel_err": float(rel.max()) if rel.size else 0.0,
            "mean_rel_err": float(rel.mean()) if rel.size else 0.0,
            "cpu_s": round(cpu, 4), "parts": -(-n // part)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=None, help="default: the 9 shipped")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--poses", type=int, default=256)
    ap.add_argument("--part", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--sets", default="benchmarks/data/real_contact_sets.npz")
    ap.add_argument("--out", default="bench_out/epsilon_real_sets.json")
    ap.add_argument("--first-seed", type=int, default=0, help="first pose seed harvested")
    ap.add_argument("--starts", type=int, default=None,
                    help="start directions (default: the trial's, protocol.TRIAL_STARTS)")
    ap.add_argument("--eigen-starts", type=int, default=None,
                    help="how many of --starts are eigen-directions (needs --starts)")
    args = ap.parse_args(argv)
    if min(args.seeds, args.poses, args.part, args.repeats) < 1:
        ap.error("--seeds, --poses, --part and --repeats must be >= 1")
    if args.first_seed < 0:
        ap.error("--first-seed must be >= 0")
    if (args.starts is None) != (args.eigen_starts is None):
        ap.error("give --starts and --eigen-starts together")
    if args.starts is not None and not 0 <= args.eigen_starts <= args.starts - 7:
        ap.error("--starts must be >= 7 (a simplex) and --eigen-starts in 0 ... starts - 7")

    import jaxgrasp as jg

    jg.enable_compilation_cache()
    names = args.objects or list(jg.objects.names())
    path = Path(args.sets)
    if path.exists():
        sets = load_sets(path)
        missing = [n for n in names if n not in sets]
        if missing:
            ap.error(f"{path} has no sets of {missing}: delete it to harvest again")
    else:
        sets = harvest(names, args.seeds, args.poses, args.first_seed)
        save_sets(path, sets)
    rows = {name: measure(sets[name], args.part, args.repeats, args.starts, args.eigen_starts)
            for name in names}
    for name, r in rows.items():
        print(f"{name:13s} {r['sets']:5d} sets  Qhull misses {r['qhull_misses']}  "
              f"max rel err {r['max_rel_err']:.2e}  CPU {r['cpu_s']:.3f} s ({r['parts']} parts)")
    total = {"sets": sum(r["sets"] for r in rows.values()),
             "qhull_misses": sum(r["qhull_misses"] for r in rows.values()),
             "cpu_s": round(sum(r["cpu_s"] for r in rows.values()), 4)}
    print(f"total: {total}")
    result = {"machine": platform.machine(), "processor": platform.processor(),
              "sets_file": str(path), "part": args.part, "starts": args.starts,
              "eigen_starts": args.eigen_starts, "objects": rows, "total": total}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
