"""Epsilon evaluations per second: batched JAX vs the Qhull reference loop, and agreement.

    .venv/bin/python benchmarks/epsilon_speed.py [--batches 1 64 1024] [--kmax 8 16]
        [--num-agree 1000] [--out bench_out/epsilon_speed.json]

Random grasps (fixed seed): 2..kmax contacts on a 2-6 cm shell around the center of mass,
normals roughly inward, friction 0.2-1.0, padded to ``kmax`` masked slots (``kmax = 8`` is the
physics trial's contact buffer, 16 the largest set we test). For each ``kmax`` and batch size
``B``: compile time of ``jit(vmap(epsilon))`` (first call minus a warm call) and warm
evaluations/s (best of ``--repeats``; also per CPU-second of this process, which is the
fairer number on a shared machine); for the reference, evaluations/s of a Python loop over
``epsilon_qhull`` on the agreement set. Agreement on ``--num-agree`` grasps per ``kmax``:
fraction within 1% relative or 1e-4 absolute of Qhull, max relative error where
Qhull > 1e-3, and zero/non-zero mismatches.
"""

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np


def random_grasps(n, kmax, seed=0, radius=0.08):
    """``n`` random grasps with 2..kmax contacts (see the module docstring); arrays (n, ...)."""
    rng = np.random.default_rng(seed)
    P, N = np.zeros((n, kmax, 3)), np.zeros((n, kmax, 3))
    M = np.zeros((n, kmax), bool)
    com = rng.normal(0.0, 0.01, (n, 3))
    for i in range(n):
        k = int(rng.integers(2, kmax + 1))
        d = rng.standard_normal((k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        nrm = -d + 0.4 * rng.standard_normal((k, 3))
        slots = rng.permutation(kmax)[:k]
        P[i, slots] = com[i] + d * rng.uniform(0.02, 0.06) * rng.uniform(0.7, 1.0, (k, 1))
        N[i, slots] = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
        M[i, slots] = True
    mu = rng.uniform(0.2, 1.0, n)
    return P, N, M, mu, com, np.full(n, radius)


def _take(arrays, idx):
    return [a[idx] for a in arrays]


def time_jax(fn, arrays, repeats):
    import jax

    t0 = time.perf_counter()
    jax.block_until_ready(fn(*arrays))
    first = time.perf_counter() - t0
    best, best_cpu = np.inf, np.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(*arrays))
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return first - best, best, best_cpu


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_out/epsilon_speed.json")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--kmax", type=int, nargs="+", default=[8, 16])
    parser.add_argument("--num-agree", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp

    import jaxgrasp as jg
    from jaxgrasp import quality

    jg.enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR"))
    fn = jax.jit(jax.vmap(quality.epsilon))
    speed, agreement = [], []
    for kmax in args.kmax:
        n = max(args.num_agree, max(args.batches))
        grasps = random_grasps(n, kmax, seed=kmax)
        f32 = [jnp.asarray(a, jnp.float32) for a in grasps]

        # Reference loop, timed on the agreement set.
        sel = slice(0, args.num_agree)
        t0, c0 = time.perf_counter(), time.process_time()
        ref = np.array([quality.epsilon_qhull(*g) for g in zip(*_take(grasps, sel), strict=True)])
        qhull_s, qhull_cpu = time.perf_counter() - t0, time.process_time() - c0
        speed.append({"impl": "qhull", "kmax": kmax, "batch": 1, "compile_s": 0.0,
                      "run_s": round(qhull_s, 4), "cpu_s": round(qhull_cpu, 4),
                      "evals_per_s": round(args.num_agree / qhull_s, 1),
                      "evals_per_cpu_s": round(args.num_agree / qhull_cpu, 1)})
        print(f"kmax={kmax:2d} qhull loop      {speed[-1]['evals_per_s']:10.1f} evals/s  "
              f"{speed[-1]['evals_per_cpu_s']:10.1f} evals/cpu-s", flush=True)

        for batch in args.batches:
            compile_s, run_s, cpu_s = time_jax(fn, _take(f32, slice(0, batch)), args.repeats)
            speed.append({"impl": "jax", "kmax": kmax, "batch": batch,
                          "compile_s": round(compile_s, 3), "run_s": round(run_s, 5),
                          "cpu_s": round(cpu_s, 5), "evals_per_s": round(batch / run_s, 1),
                          "evals_per_cpu_s": round(batch / cpu_s, 1)})
            r = speed[-1]
            print(f"kmax={kmax:2d} jax B={batch:5d}    {r['evals_per_s']:10.1f} evals/s  "
                  f"{r['evals_per_cpu_s']:10.1f} evals/cpu-s  compile {compile_s:5.1f} s",
                  flush=True)

        # Agreement, in chunks of the largest batch (already compiled).
        chunk = max(args.batches)
        out = []
        for s in range(0, args.num_agree, chunk):
            part = [a[s : min(s + chunk, args.num_agree)] for a in f32]
            pad = chunk - part[0].shape[0]
            part = [jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]) for a in part]
            out.append(np.asarray(fn(*part))[: chunk - pad])
        out = np.concatenate(out).astype(float)
        err = np.abs(out - ref)
        ok = err <= np.maximum(1e-4, 0.01 * ref)
        pos = ref > 1e-3
        rel = err[pos] / ref[pos]
        agreement.append({
            "kmax": kmax,
            "num": int(args.num_agree),
            "num_positive": int(pos.sum()),
            "fraction_within_tol": float(ok.mean()),
            "max_rel_err": float(rel.max()) if rel.size else 0.0,
            "p99_rel_err": float(np.quantile(rel, 0.99)) if rel.size else 0.0,
            "max_abs_err": float(err.max()),
            "jax_zero_ref_positive": int(((out == 0) & (ref > 1e-4)).sum()),
            "jax_positive_ref_zero": int(((out > 1e-4) & (ref == 0)).sum()),
            "jax_below_ref": int((out < ref - 1e-5).sum()),
        })
        a = agreement[-1]
        print(f"kmax={kmax:2d} agreement {a['fraction_within_tol']:.4f} of {a['num']} "
              f"({a['num_positive']} positive), max rel err {a['max_rel_err']:.2e}, "
              f"p99 {a['p99_rel_err']:.2e}", flush=True)

    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "device": str(jax.devices()[0]),
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "load_avg": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }
    out_path.write_text(json.dumps({"meta": meta, "speed": speed, "agreement": agreement},
                                   indent=2))
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main()
