"""Trials/s of MJX-JAX, MJX-Warp and MuJoCo C at B = 64...16384 plus outcome agreement, as
JSON (run by ``benchmarks/gpu_check.sh``; UNTESTED ON A GPU: written and checked with
``--quick`` on a 2-core CPU, where no GPU was lent).

    .venv/bin/python benchmarks/gpu_check.py [--object pitcher] [--batch 64 256 1024 4096 16384]
        [--backends mjx mjx-warp mujoco] [--agree-n 256] [--budget-s 280] [--quick]
        [--out bench_out/gpu_check.json]

Per backend and B (ascending): the first call (compile + run) and one warm call on the same
poses (``backend_agreement.agreement_poses``: 25 % collide at placement); trials/s = B / warm
seconds, full trial (contacts + epsilon). A cell is skipped (recorded as such) once the
backend's next cell would, at its last per-trial cost and compile time, overrun the budget.
Agreement: the outcomes of each backend against MuJoCo C on the first ``--agree-n`` poses
(``backend_agreement.compare``). ``--quick``: B = 8, 16, agreement on 16 poses (CPU check).
"""

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--batch", type=int, nargs="+", default=[64, 256, 1024, 4096, 16384])
    ap.add_argument("--backends", nargs="+", default=["mjx", "mjx-warp", "mujoco"])
    ap.add_argument("--agree-n", type=int, default=256)
    ap.add_argument("--budget-s", type=float, default=280.0)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="bench_out/gpu_check.json")
    args = ap.parse_args(argv)
    if args.quick:
        args.batch, args.agree_n = [8, 16], 16
    t_start = time.perf_counter()

    import jax
    import mujoco
    import numpy as np

    import jaxgrasp as jg
    from jaxgrasp.physics import warp_backend

    jg.enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR"))
    import backend_agreement as ba  # a sibling script: sys.path[0] is benchmarks/

    obj = jg.objects.load(args.object)
    scene = jg.physics.load_scene(obj)
    backends = [b for b in args.backends if b != "mjx-warp" or warp_backend.warp_available()]
    trials = {b: jg.physics.make_trial(scene, backend=b) for b in backends}
    engine = trials["mujoco"].engine if "mujoco" in trials else \
        jg.physics.mujoco_backend.MujocoEngine(scene)
    n_poses = max(max(args.batch), args.agree_n)
    poses = np.asarray(ba.agreement_poses(obj, n_poses, 0, placement=engine.place), np.float32)
    out = {"meta": {
        "object": args.object, "device": str(jax.devices()[0]),
        "device_kind": jax.devices()[0].device_kind, "jax_backend": jax.default_backend(),
        "cpu_count": os.cpu_count(), "platform": platform.platform(),
        "load_average_1min": os.getloadavg()[0],
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
        "skipped_backends": sorted(set(args.backends) - set(backends)),
        "note": "full trial (contacts + epsilon); untested on a GPU when written",
        "command": "benchmarks/gpu_check.py " + " ".join(sys.argv[1:] if argv is None else argv),
    }, "throughput": [], "agreement": {}}
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)

    def write():
        out["meta"]["wall_s"] = round(time.perf_counter() - t_start, 1)
        path.write_text(json.dumps(out, indent=2))

    def left():
        return args.budget_s - (time.perf_counter() - t_start)

    # Agreement first: small, and the number that says whether the rates mean anything.
    agree = poses[: args.agree_n]
    res = {}
    for b in backends:
        t = time.perf_counter()
        res[b] = jax.device_get(trials[b](agree))
        out["agreement"].setdefault("first_call_s", {})[b] = round(time.perf_counter() - t, 2)
    if "mujoco" in res:
        for b in backends:
            if b != "mujoco":
                s = ba.compare(res[b], res["mujoco"])
                out["agreement"][f"{b}_vs_mujoco"] = {k: s[k] for k in (
                    "n", "agreement", "confusion_mjx_rows_c_cols", "eps_within_tol",
                    "eps_rel_diff_median", "unstable_mjx", "unstable_c")}
    write()
    print(json.dumps(out["agreement"]), flush=True)

    for b in backends:
        per_trial, compile_s = None, 0.0
        for B in sorted(args.batch):
            g = poses[:B]
            if per_trial is not None and compile_s + 2 * per_trial * B > left():
                out["throughput"].append({"backend": b, "batch": B, "skipped": "time budget"})
                continue
            t = time.perf_counter()
            jax.block_until_ready(trials[b](g))
            first = time.perf_counter() - t
            t = time.perf_counter()
            jax.block_until_ready(trials[b](g))
            warm = time.perf_counter() - t
            per_trial, compile_s = warm / B, max(first - warm, 0.0)
            out["throughput"].append({"backend": b, "batch": B, "first_call_s": round(first, 3),
                                      "warm_s": round(warm, 4),
                                      "trials_per_s": round(B / warm, 1)})
            print(json.dumps(out["throughput"][-1]), flush=True)
            write()
    write()
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
