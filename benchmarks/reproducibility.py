"""How reproducible are trial outcomes? Same batch twice, other batch sizes, other CPU code.

    .venv/bin/python benchmarks/reproducibility.py --out bench_out/repro_default.npz
    XLA_FLAGS=--xla_cpu_max_isa=SSE4_2 .venv/bin/python benchmarks/reproducibility.py \
        --out bench_out/repro_sse42.npz --compare bench_out/repro_default.npz

On ``--num-poses`` fixed pitcher poses (``backend_agreement.agreement_poses``, seed 0) it runs
the MuJoCo C trial at two batch sizes and the MJX trial at two batch sizes, each batch size
twice, and counts the outcomes that differ. ``--compare`` counts the flips against a file
written by another run (e.g. the same machine with XLA limited to an older instruction set,
or another CPU). Writes the outcomes (npz) and a JSON summary beside them.
"""

import argparse
import json
import platform
from pathlib import Path

import numpy as np
from backend_agreement import agreement_poses, run_batched


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher")
    ap.add_argument("--num-poses", type=int, default=512)
    ap.add_argument("--c-batches", default="1,512")
    ap.add_argument("--mjx-batches", default="16,64")
    ap.add_argument("--out", type=Path, default=Path("bench_out/repro.npz"))
    ap.add_argument("--compare", type=Path, default=None)
    a = ap.parse_args(argv)

    import jax

    import jaxgrasp as jg
    from jaxgrasp.physics import load_scene, make_trial

    jg.enable_compilation_cache()
    obj = jg.objects.load(a.object)
    scene = load_scene(obj)
    trials = {"mujoco": make_trial(scene, backend="mujoco"), "mjx": make_trial(scene)}
    poses = agreement_poses(obj, a.num_poses, 0, placement=trials["mujoco"].engine.place)
    out, summary = {"poses": poses}, {"object": a.object, "num_poses": a.num_poses,
                                      "platform": platform.processor() or platform.machine(),
                                      "xla_flags": __import__("os").environ.get("XLA_FLAGS", ""),
                                      "runs": {}}
    for backend, batches in (("mujoco", a.c_batches), ("mjx", a.mjx_batches)):
        first = None
        for b in (int(s) for s in batches.split(",")):
            runs = [run_batched(trials[backend], poses, b) for _ in range(2)]
            o = [np.asarray(r.outcome) for r in runs]
            out[f"{backend}_b{b}"] = o[0]
            out[f"{backend}_b{b}_eps"] = np.asarray(runs[0].epsilon)
            rec = {"repeat_flips": int((o[0] != o[1]).sum()),
                   "repeat_bit_identical": all(
                       np.array_equal(np.asarray(x), np.asarray(y))
                       for x, y in zip(runs[0], runs[1], strict=True)),
                   "outcome_counts": np.bincount(o[0], minlength=4).tolist()}
            if first is None:
                first = (b, o[0])
            else:
                rec[f"flips_vs_b{first[0]}"] = int((o[0] != first[1]).sum())
            summary["runs"][f"{backend}_b{b}"] = rec
            print(backend, b, rec, flush=True)
    if a.compare is not None:
        other = np.load(a.compare)
        if not np.array_equal(other["poses"], poses):
            raise SystemExit(f"{a.compare} holds other poses")
        summary["flips_vs_compare"] = {k: int((out[k] != other[k]).sum()) for k in out
                                       if k != "poses" and not k.endswith("_eps")
                                       and k in other}
        print("flips vs", a.compare, summary["flips_vs_compare"])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(a.out, **out)
    a.out.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    print("wrote", a.out, "devices", jax.devices())


if __name__ == "__main__":
    main()
