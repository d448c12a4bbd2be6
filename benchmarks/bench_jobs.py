"""Wall time of ``python -m jaxgrasp.bench`` at several ``--jobs``, run back to back, and
whether the saved results are equal to those of the first setting (``--jobs 1``).

    python benchmarks/bench_jobs.py --jobs 1 2 3 --out bench_out/s7/jobs
    python benchmarks/bench_jobs.py --profile paper --backend mujoco --jobs 3 --out ...

Each setting runs in a fresh process (``--no-figures --no-throughput --quiet``) into
``<out>/jobs<N>``; the summary (wall and CPU seconds, CPU use = CPU s / wall s, 1-min load
average before and after, equal results) goes to ``<out>/summary.json``. On a shared machine
compare only settings measured in the same time window.
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def compare(a: Path, b: Path) -> dict:
    """Saved results under ``a/runs`` and ``b/runs``: which differ (arrays), which are missing."""
    import numpy as np

    from jaxgrasp.learn.files.results import load

    ra, rb = Path(a) / "runs", Path(b) / "runs"
    dirs = sorted(p.parent.relative_to(ra) for p in ra.rglob("result.json")
                  if ".stale" not in p.parts)
    differ, missing = {}, []
    for d in dirs:
        if not (rb / d / "result.json").is_file():
            missing.append(str(d))
            continue
        x, y = load(ra / d).arrays(), load(rb / d).arrays()
        bad = sorted(k for k in x.keys() | y.keys()
                     if k not in x or k not in y or not np.array_equal(x[k], y[k]))
        if bad:
            differ[str(d)] = bad
    return {"results": len(dirs), "equal": not differ and not missing, "differ": differ,
            "missing": missing}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    p.add_argument("--profile", default="default")
    p.add_argument("--backend", default="mujoco")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("extra", nargs="*", help="more bench flags (after --)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("JAXGRASP_CACHE_DIR", str(REPO / ".cache" / "jax"))
    runs = []
    for jobs in args.jobs:
        out = args.out / f"jobs{jobs}"
        cmd = [sys.executable, "-m", "jaxgrasp.bench", "--profile", args.profile,
               "--backend", args.backend, "--out", str(out), "--no-figures",
               "--no-throughput", "--quiet", "--jobs", str(jobs), *args.extra]
        load0 = os.getloadavg()[0]
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
        rec = {"jobs": jobs, "cmd": " ".join(cmd[1:]), "returncode": proc.returncode,
               "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
               "cpu_use": round(cpu / wall, 2), "load_before": load0,
               "load_after": os.getloadavg()[0],
               "started": time.strftime("%H:%M:%S", time.localtime(time.time() - wall))}
        if proc.returncode != 0:
            rec["stderr_tail"] = proc.stderr[-2000:]
        runs.append(rec)
        print(json.dumps(rec), flush=True)
        if len(runs) > 1:
            rec["same_results_as_first"] = compare(args.out / f"jobs{args.jobs[0]}", out)
            print(json.dumps(rec["same_results_as_first"]), flush=True)
        (args.out / "summary.json").write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()
