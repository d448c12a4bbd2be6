"""Draw ``docs/scaling.png`` from ``benchmarks/scaling.py --cost-growth`` JSON.

    .venv/bin/python benchmarks/plot_scaling.py [--out docs/scaling.png] [JSON ...]

(default input: bench_out/cost_growth.json and bench_out/cost_growth_learn.json where they
exist; the rows of every input are drawn together).

Left: MuJoCo C full-trial trials/s vs batch size; right: learning proposals/s vs chains
(``jg.learn.active``, Kameleon + GDMC), both log-log, with the machine and its load noted.
"""

import json
import sys
from pathlib import Path


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    dst = Path("docs/scaling.png")
    if "--out" in argv:
        i = argv.index("--out")
        dst = Path(argv[i + 1])
        del argv[i : i + 2]
    srcs = [Path(a) for a in argv] or [p for p in (Path("bench_out/cost_growth.json"),
                                                   Path("bench_out/cost_growth_learn.json"))
                                       if p.exists()]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, loads, cores = [], [], set()
    for src in srcs:
        data = json.loads(src.read_text())
        rows += data["results"]
        loads.append(data["meta"].get("load_average_1min", float("nan")))
        cores.add(data["meta"].get("cpu_count"))
    trial = [r for r in rows if r["target"] == "trial_mujoco_full"]
    learn = [r for r in rows if r["target"].startswith("learn_")]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, pts, x, y, xl, yl, title in (
        (axes[0], trial, "batch", "trials_per_s", "batch size B", "trials / s",
         "MuJoCo C full trial (contacts + epsilon)"),
        (axes[1], learn, "chains", "proposals_per_s", "chains", "proposals / s",
         "learning (jg.learn.active, Kameleon + GDMC)"),
    ):
        if pts:
            ax.plot([p[x] for p in pts], [p[y] for p in pts], "o-")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    obj = (trial or learn or [{}])[0].get("object", "?")
    load = ", ".join(f"{x:.1f}" for x in loads)
    fig.suptitle(f"How cost grows ({obj}; {'/'.join(map(str, sorted(cores)))} shared CPU "
                 f"cores; 1-min load average {load} when written, the run's own included)",
                 fontsize=10)
    fig.tight_layout()
    dst.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(dst, dpi=110)
    print("wrote", dst)


if __name__ == "__main__":
    main()
