"""Physics never poisons a chain: random and adversarial grasp poses through both backends.

    .venv/bin/python benchmarks/robustness.py [--num-poses 100000] [--mjx-poses 256]
                                              [--out bench_out/robustness.json]

Pushes pose families (uniform around the object, inside its material and its hollow, far
away, under the support plane, near-zero / zero / huge quaternions, NaN/inf entries) through
the grasp trial (``jg.physics.make_trial``) and the target density
(``jax.vmap(jaxgrasp.density.grasp_logdensity(trial))``, the path the MCMC chains take) on
the shipped pitcher, and reports per backend and family:

- the number of non-finite log-densities (must be 0) and of non-finite trial fields;
- the number of unstable trials (``res.unstable``) and their outcomes: each must be a failure
  (COLLISION/MISS) with epsilon 0 and a density at the floor;
- the outcome histogram.

MuJoCo C runs every pose (batch 1024); MJX is ~15 trials/s on a 2-core CPU, so it runs on a
per-family subset (``--mjx-poses`` in all, batch ``--mjx-batch``), recorded in the JSON.
"""

import argparse
import contextlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: Progress stream (the real stderr even while MuJoCo's C warnings are captured).
_ERR = sys.stderr


@contextlib.contextmanager
def capture_c_stderr(enabled=True):
    """Send fd 2 (MuJoCo C's "simulation is unstable" warnings) to a temp file; yields a
    list that receives the count of ``WARNING`` lines on exit. Progress goes to ``_ERR``."""
    global _ERR
    counts = []
    if not enabled:
        yield counts
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as log:
        os.dup2(log.fileno(), 2)
        _ERR = os.fdopen(os.dup(saved), "w")
        try:
            yield counts
        finally:
            _ERR.flush()
            _ERR.close()
            _ERR = sys.stderr
            os.dup2(saved, 2)
            os.close(saved)
            log.seek(0)
            counts.append(sum(line.count(b"WARNING") for line in log))

OUTCOMES = ("SUCCESS", "SLIPPED", "COLLISION", "MISS")


def _unit_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _near(obj, rng, n, reach=0.04):
    """Grasp centers in the object's bounding box grown by ``reach``, above the table."""
    lo, hi = np.asarray(obj.mesh.bounds, float)
    lo, hi = lo - reach, hi + reach
    lo[2] = max(lo[2], obj.support_z)
    return rng.uniform(lo, hi, (n, 3))


def pose_families(obj, n, seed=0):
    """``{family: (n, 7) float32 poses}`` (random and adversarial), deterministic in ``seed``.

    Families: ``uniform`` (center near the object, uniform orientation), ``inside_material``
    (surface points pushed 0-2 mm into the walls), ``inside_hollow`` (near the object's axis,
    inside its bounding box), ``far`` (0.5 m - 1e6 m away), ``below_support`` (z < support),
    ``near_zero_quat`` (norms 1e-30 .. 1e-6, and exact zeros), ``zero_quat``, ``huge_quat``
    (norms 1e3 .. 1e38, some overflowing float32 squares), ``nonfinite`` (one to seven
    NaN/+inf/-inf entries), ``huge_position`` (|x| up to 3e38).
    """
    rng = np.random.default_rng(seed)
    fam = {}
    fam["uniform"] = np.concatenate([_near(obj, rng, n), _unit_quats(rng, n)], 1)

    pts, face = obj.mesh.sample(n, return_index=True, seed=int(rng.integers(2**31)))
    pts = pts - obj.mesh.face_normals[face] * rng.uniform(0, 2e-3, (n, 1))
    fam["inside_material"] = np.concatenate([pts, _unit_quats(rng, n)], 1)

    lo, hi = np.asarray(obj.mesh.bounds, float)
    center = np.array([obj.com[0], obj.com[1], 0.0])
    r = rng.uniform(0, 0.03, n)
    a = rng.uniform(0, 2 * np.pi, n)
    hollow = center + np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(lo[2], hi[2], n)], 1)
    fam["inside_hollow"] = np.concatenate([hollow, _unit_quats(rng, n)], 1)

    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    dist = 10 ** rng.uniform(np.log10(0.5), 6, (n, 1))
    fam["far"] = np.concatenate([obj.com + direction * dist, _unit_quats(rng, n)], 1)

    below = _near(obj, rng, n)
    below[:, 2] = obj.support_z - 10 ** rng.uniform(-4, 0, n)
    fam["below_support"] = np.concatenate([below, _unit_quats(rng, n)], 1)

    scale = 10 ** rng.uniform(-30, -6, (n, 1))
    scale[rng.random(n) < 0.1] = 0.0
    fam["near_zero_quat"] = np.concatenate([_near(obj, rng, n), _unit_quats(rng, n) * scale], 1)

    fam["zero_quat"] = np.concatenate([_near(obj, rng, n), np.zeros((n, 4))], 1)

    scale = 10 ** rng.uniform(3, 38, (n, 1))
    fam["huge_quat"] = np.concatenate([_near(obj, rng, n), _unit_quats(rng, n) * scale], 1)

    bad = np.concatenate([_near(obj, rng, n), _unit_quats(rng, n)], 1)
    k = rng.integers(1, 8, n)
    for i in range(n):
        cols = rng.choice(7, k[i], replace=False)
        bad[i, cols] = rng.choice([np.nan, np.inf, -np.inf], k[i])
    fam["nonfinite"] = bad

    huge = rng.normal(size=(n, 3)) * 10 ** rng.uniform(3, 38, (n, 1))
    fam["huge_position"] = np.concatenate([huge, _unit_quats(rng, n)], 1)

    with np.errstate(over="ignore", invalid="ignore"):
        return {k: v.astype(np.float32) for k, v in fam.items()}


def run_family(trial, vdens, poses, batch, floor, progress=None):
    """Per-family counts of one backend: outcomes, unstable trials, non-finite values.

    ``vdens = jax.jit(jax.vmap(grasp_logdensity(trial)))``, built once per backend.
    """
    import jax

    hist = np.zeros(4, np.int64)
    unstable_hist = np.zeros(4, np.int64)
    stats = dict(
        poses=int(len(poses)),
        nonfinite_logp=0,
        nonfinite_trial_fields=0,
        logp_below_floor=0,
        unstable=0,
        unstable_not_failure=0,
        unstable_nonzero_epsilon=0,
        unstable_logp_above_floor=0,
        density_outcome_mismatch=0,
        errors=[],
    )
    log_floor = np.float32(np.log(np.float32(floor)))
    for start in range(0, len(poses), batch):
        g = poses[start : start + batch]
        n = len(g)
        # Pad the last batch to the compiled shape (a new shape would recompile both paths)
        # with NaN poses: collisions that cost no rollout.
        gp = np.concatenate([g, np.full((batch - n, 7), np.nan, g.dtype)]) if n < batch else g
        try:
            res = jax.tree.map(lambda x, n=n: x[:n], jax.device_get(trial(gp)))
            logp, aux = jax.tree.map(lambda x, n=n: x[:n], jax.device_get(vdens(gp)))
        except Exception as e:  # a crash is a finding, not the end of the benchmark
            stats["errors"].append(f"{type(e).__name__}: {e}"[:300])
            continue
        finite = np.ones(len(g), bool)
        for val in res:
            v = np.asarray(val)
            if v.dtype.kind == "f":
                finite &= np.all(np.isfinite(v.reshape(len(g), -1)), axis=1)
        stats["nonfinite_trial_fields"] += int(np.sum(~finite))
        stats["nonfinite_logp"] += int(np.sum(~np.isfinite(logp)))
        stats["logp_below_floor"] += int(np.sum(logp < log_floor))
        out = np.asarray(res.outcome)
        hist += np.bincount(out, minlength=4)[:4]
        stats["density_outcome_mismatch"] += int(np.sum(np.asarray(aux["outcome"]) != out))
        u = np.asarray(res.unstable)
        stats["unstable"] += int(u.sum())
        unstable_hist += np.bincount(out[u], minlength=4)[:4]
        stats["unstable_not_failure"] += int(np.sum(u & (out < 2)))
        stats["unstable_nonzero_epsilon"] += int(np.sum(u & (np.asarray(res.epsilon) != 0)))
        stats["unstable_logp_above_floor"] += int(np.sum(u & (logp > log_floor)))
        if progress:
            progress(min(start + batch, len(poses)))
    stats["outcomes"] = dict(zip(OUTCOMES, map(int, hist), strict=True))
    stats["unstable_outcomes"] = dict(zip(OUTCOMES, map(int, unstable_hist), strict=True))
    return stats


#: ``max_speed`` (m/s, rad/s) of the forced-instability check: closing fingers move faster, so
#: every rollout that starts is flagged unstable (the blow-up path, which real poses never hit).
FORCED_MAX_SPEED = 1e-3


def forced_unstable(trial, vdens, poses, batch, floor):
    """The unstable-trial bookkeeping on real rollouts: ``poses`` through a MuJoCo C trial
    whose blow-up threshold (``TrialParams.max_speed``, read on the host by
    ``trial.engine``) is lowered so that every rollout that starts exceeds it; the compiled
    trial and density are reused as they are."""
    from dataclasses import replace

    engine = trial.engine
    saved = engine.params
    engine.params = replace(saved, max_speed=FORCED_MAX_SPEED)
    try:
        stats = run_family(trial, vdens, poses, batch, floor)
    finally:
        engine.params = saved
    stats["max_speed"] = FORCED_MAX_SPEED
    return stats


def run_backend(scene, backend, families, batch, floor, quiet=False, forced_poses=None):
    import jax

    import jaxgrasp as jg
    from jaxgrasp.density import grasp_logdensity

    trial = jg.physics.make_trial(scene, backend=backend)
    vdens = jax.jit(jax.vmap(grasp_logdensity(trial, floor=floor)))
    t0 = time.perf_counter()
    # Compile both paths once on the batch shape (not timed as throughput).
    warm = next(iter(families.values()))[:batch]
    jax.block_until_ready(trial(warm))
    jax.block_until_ready(vdens(warm))
    compile_s = time.perf_counter() - t0
    per_family = {}
    t0 = time.perf_counter()
    for name, poses in families.items():
        tf = time.perf_counter()

        def progress(done, name=name, total=poses.shape[0]):
            if not quiet:
                print(f"\r  [{backend}] {name:16s} {done:7d}/{total}", end="", file=_ERR,
                      flush=True)

        per_family[name] = run_family(trial, vdens, poses, batch, floor, progress)
        per_family[name]["seconds"] = round(time.perf_counter() - tf, 2)
        if not quiet:
            s = per_family[name]
            print(f"  nan_logp={s['nonfinite_logp']} unstable={s['unstable']} "
                  f"{s['outcomes']} ({s['seconds']} s)", file=_ERR, flush=True)
    total = {
        k: sum(f[k] for f in per_family.values())
        for k in ("poses", "nonfinite_logp", "nonfinite_trial_fields", "logp_below_floor",
                  "unstable", "unstable_not_failure", "unstable_nonzero_epsilon",
                  "unstable_logp_above_floor", "density_outcome_mismatch")
    }
    total["outcomes"] = {o: sum(f["outcomes"][o] for f in per_family.values()) for o in OUTCOMES}
    total["unstable_outcomes"] = {
        o: sum(f["unstable_outcomes"][o] for f in per_family.values()) for o in OUTCOMES
    }
    total["errors"] = sum(len(f["errors"]) for f in per_family.values())
    seconds = time.perf_counter() - t0
    extra = {}
    if forced_poses is not None:
        extra["forced_unstable"] = forced_unstable(trial, vdens, forced_poses, batch, floor)
    return dict(**extra,
        batch=batch,
        compile_seconds=round(compile_s, 1),
        seconds=round(seconds, 1),
        poses_per_second=round(2 * total["poses"] / seconds, 1),
        note="each pose runs twice: the batched trial and the vmapped density",
        total=total,
        families=per_family,
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--num-poses", type=int, default=100_000,
                    help="poses in all for MuJoCo C, split evenly over the families")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--mjx-poses", type=int, default=256,
                    help="poses in all for MJX (0: skip), split evenly over the families")
    ap.add_argument("--mjx-batch", type=int, default=64)
    ap.add_argument("--forced-unstable-poses", type=int, default=1024,
                    help="MuJoCo C: uniform poses with the blow-up threshold lowered below "
                         "what every rollout reaches (exercises the unstable path; 0: skip)")
    ap.add_argument("--floor", type=float, default=None, help="density floor (default: library)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--backends", default="mujoco,mjx")
    ap.add_argument("--out", default="bench_out/robustness.json")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--show-mujoco-warnings", action="store_true",
                    help="let MuJoCo C print its warnings (default: count them)")
    args = ap.parse_args(argv)

    import jax
    import mujoco

    import jaxgrasp as jg
    from jaxgrasp._cache import enable_compilation_cache
    from jaxgrasp.density import DEFAULT_FLOOR

    enable_compilation_cache()
    floor = DEFAULT_FLOOR if args.floor is None else args.floor
    obj = jg.objects.load(args.object)
    scene = jg.physics.load_scene(obj)
    names = list(pose_families(obj, 1))
    report = dict(
        object=args.object,
        seed=args.seed,
        floor=floor,
        families=names,
        machine=dict(platform=platform.platform(), processor=platform.processor(),
                     jax=jax.__version__, mujoco=mujoco.__version__,
                     devices=[str(d) for d in jax.devices()]),
        backends={},
    )
    for backend in args.backends.split(","):
        total = args.num_poses if backend == "mujoco" else args.mjx_poses
        batch = args.batch if backend == "mujoco" else args.mjx_batch
        if total <= 0:
            continue
        per = max(1, total // len(names))
        fams = pose_families(obj, per, args.seed)
        if not args.quiet:
            print(f"{backend}: {per} poses x {len(names)} families, batch {batch}",
                  file=_ERR, flush=True)
        forced = None
        if args.forced_unstable_poses > 0 and backend == "mujoco":
            forced = pose_families(obj, args.forced_unstable_poses, args.seed + 1)["uniform"]
        with capture_c_stderr(not args.show_mujoco_warnings) as warnings:
            rep = run_backend(scene, backend, fams, batch, floor, args.quiet, forced)
        rep["mujoco_c_warnings"] = warnings[0] if warnings else None
        if forced is not None:
            f = rep["forced_unstable"]
            print(f"{backend} forced instability (max_speed {f['max_speed']}): {f['poses']} "
                  f"uniform poses, unstable {f['unstable']}, outcomes of the unstable "
                  f"{f['unstable_outcomes']}, not failures {f['unstable_not_failure']}, "
                  f"non-finite log-densities {f['nonfinite_logp']}")
        rep["poses_per_family"] = per
        if backend == "mjx":
            rep["subset_note"] = (f"MJX on this CPU runs ~15 trials/s: a subset of {per} poses "
                                  f"per family (same generator and seed as MuJoCo C)")
        report["backends"][backend] = rep
        t = rep["total"]
        print(f"{backend}: {t['poses']} poses, non-finite log-densities {t['nonfinite_logp']}, "
              f"non-finite trial fields {t['nonfinite_trial_fields']}, unstable {t['unstable']} "
              f"(outcomes {t['unstable_outcomes']}, not failures {t['unstable_not_failure']}), "
              f"outcomes {t['outcomes']}, errors {t['errors']}, {rep['seconds']} s, "
              f"MuJoCo C warnings {rep['mujoco_c_warnings']}")
    checks = [r["total"] for r in report["backends"].values()]
    checks += [r["forced_unstable"] for r in report["backends"].values() if "forced_unstable" in r]
    ok = all(
        r["nonfinite_logp"] == 0
        and r["nonfinite_trial_fields"] == 0
        and r["unstable_not_failure"] == 0
        and r["unstable_nonzero_epsilon"] == 0
        and r["unstable_logp_above_floor"] == 0
        and not r["errors"]
        for r in checks
    )
    report["passed"] = ok
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2))
    print(f"{'PASS' if ok else 'FAIL'}; wrote {out}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
