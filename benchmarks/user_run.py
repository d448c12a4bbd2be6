"""A user's learning run, split into its phases: what a call of ``jg.learn.active`` with the
defaults spends where, and how it compares with the bare trial on the same grasps.

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/user_run.py \
        [--objects pitcher] [--iterations 1000] [--burn-in 100] [--chains 8] \
        [--out bench_out/user_run.json]

Per object, in one process, two calls of ``jg.learn.active`` (Kameleon + GDMC, biased sketch,
backend mujoco, the default ``LearnParams`` up to ``--iterations``/``--burn-in``): seed 0, then
seed 1 with the first call's demonstrations. Each row splits the call's wall time into
``load`` (``jg.objects.load``: mesh and convex pieces, decomposed offline for the shipped
objects), ``scene`` (scene and trial, :func:`jaxgrasp.learn.sim.shared_simulator`), ``demos``,
``sketch``, ``sampling`` (the chains) and ``writing`` (``LearnResult.save``); ``compile_s``
is the XLA compilation and lowering inside those phases (per phase in ``compile_by_phase``),
``programs`` the XLA programs built (``cache_hits`` of them read from the persistent cache,
``compiled`` the names of the others; the run's sampler compiles in a thread during the
demo search and is counted there). ``bare_s`` is the bare trial
(:class:`~jaxgrasp.learn.Simulator` host calls, compiled beforehand) on every grasp the call
simulated, at B = 64 and at the run's batch (``--chains``); ``ratio`` is wall over bare trial.

A fresh process with a warm persistent cache (``JAXGRASP_CACHE_DIR``) is the first row of a
second invocation. Timings on a shared machine are rough.
"""

import argparse
import json
import os
import platform
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

BARE_BATCHES = (64,)


class PhaseClock:
    """Wall time per phase of a learning call and the XLA programs built in each (JAX's
    monitoring events, attributed to the phase running when they end)."""

    BUILD = "/jax/core/compile/backend_compile_duration"
    LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
    HIT = "/jax/compilation_cache/cache_hits"

    def __init__(self):
        self.phase = "other"
        self.reset()
        self._hit = threading.local()

    def reset(self):
        self.wall, self.compile_s, self.compiled = {}, {}, []
        self.programs = self.cache_hits = 0

    @contextmanager
    def __call__(self, phase):
        outer, self.phase = self.phase, phase
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.wall[phase] = self.wall.get(phase, 0.0) + time.perf_counter() - t0
            self.phase = outer

    def on_event(self, event, **kwargs):
        if event == self.HIT:  # recorded inside the build it belongs to, on its thread
            self._hit.flag = True

    def on_duration(self, event, secs, **kwargs):
        if event not in (self.BUILD, self.LOWER):
            return
        self.compile_s[self.phase] = self.compile_s.get(self.phase, 0.0) + secs
        if event == self.BUILD:
            self.programs += 1
            if getattr(self._hit, "flag", False):
                self.cache_hits += 1
                self._hit.flag = False
            elif secs >= 0.1:
                self.compiled.append((self.phase, kwargs.get("fun_name"), round(secs, 2)))

    def install(self):
        from jax import monitoring

        monitoring.register_event_listener(self.on_event)
        monitoring.register_event_duration_secs_listener(self.on_duration)


def instrument(clock):
    """Time the phases of ``jg.learn.active``: its demo search, biased sketch and chains."""
    from jaxgrasp.learn import active_learning, pipeline

    def timed(phase, fn):
        def wrapper(*args, **kwargs):
            with clock(phase):
                return fn(*args, **kwargs)
        return wrapper

    active_learning.demonstrations = timed("demos", active_learning.demonstrations)
    active_learning.biased_sketch = timed("sketch", active_learning.biased_sketch)
    pipeline.run_chains = timed("sampling", pipeline.run_chains)


@contextmanager
def recorded(sim):
    """Every grasp ``sim`` simulates inside the block (a list of (n, 7) arrays)."""
    grasps, simulate = [], sim.simulate_now

    def record(g, merged=False):
        grasps.append(g.copy())
        return simulate(g, merged)

    sim.simulate_now = record
    try:
        yield grasps
    finally:
        del sim.simulate_now


def bare_seconds(sim, grasps):
    """Seconds of ``sim`` (compiled beforehand) on ``grasps`` in calls of its batch size."""
    import numpy as np

    b = sim.batch_size
    sim(grasps[:b])  # compiles the tail at this batch, outside the timing
    t0 = time.perf_counter()
    for i in range(0, len(grasps), b):
        sim(grasps[i:i + b])
    return time.perf_counter() - t0 if len(grasps) else float(np.nan)


def one_call(clock, name, params, chains, seed, demos):
    """One ``jg.learn.active`` call with every phase timed: (row, result)."""
    import numpy as np

    import jaxgrasp as jg
    from jaxgrasp.learn.sim import shared_simulator

    clock.reset()
    t0 = time.perf_counter()
    with clock("load"):
        obj = jg.objects.load(name)
    with clock("scene"):
        sim = shared_simulator(obj, backend="mujoco", batch_size=chains)
    with recorded(sim) as grasps:
        result = jg.learn.active(obj, chains=chains, seed=seed, params=params,
                                 backend="mujoco", demos=demos, progress=False)
    with clock("writing"), tempfile.TemporaryDirectory() as tmp:
        result.save(Path(tmp) / "run")
    wall = time.perf_counter() - t0
    grasps = np.concatenate(grasps)
    call_compile_s = sum(clock.compile_s.values())
    with clock("bare"):  # its compiles (the tail at B = 64) are not the call's
        bare = {b: bare_seconds(shared_simulator(obj, backend="mujoco", batch_size=b), grasps)
                for b in sorted({*BARE_BATCHES, chains})}
    sampling = clock.wall.get("sampling", 0.0)
    row = {"object": name, "seed": seed, "chains": chains, "steps": params.num_steps,
           "demos_given": demos is not None, "trials": len(grasps),
           "wall_s": round(wall, 2), "run_seconds": round(result.info["run_seconds"], 2),
           **{f"{k}_s": round(clock.wall.get(k, 0.0), 3)
              for k in ("load", "scene", "demos", "sketch", "sampling", "writing")},
           "compile_s": round(call_compile_s, 2),
           "compile_by_phase": {k: round(v, 2) for k, v in clock.compile_s.items()},
           "sampling_without_compile_s": round(
               sampling - clock.compile_s.get("sampling", 0.0), 2),
           "programs": clock.programs, "cache_hits": clock.cache_hits,
           "compiled": clock.compiled,
           "bare_s": {str(b): round(s, 2) for b, s in bare.items()},
           "ratio": {str(b): round(wall / s, 2) for b, s in bare.items()}}
    return row, result


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=["pitcher"])
    ap.add_argument("--iterations", type=int, default=None, help="default: LearnParams'")
    ap.add_argument("--burn-in", type=int, default=None, help="default: LearnParams'")
    ap.add_argument("--chains", type=int, default=8)
    ap.add_argument("--out", default="bench_out/user_run.json")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    import jax

    import jaxgrasp as jg

    cache = jg.enable_compilation_cache()
    cache_entries = sum(1 for _ in cache.iterdir())
    import_s = time.perf_counter() - t0
    clock = PhaseClock()
    clock.install()
    instrument(clock)
    params = jg.learn.LearnParams()
    params = params.replace(**{k: v for k, v in (("iterations", args.iterations),
                                                 ("burn_in", args.burn_in)) if v is not None})
    rows = []
    out = Path(args.out)
    for name in args.objects:
        demos = None
        for seed in (0, 1):
            row, result = one_call(clock, name, params, args.chains, seed, demos)
            demos = result.demos
            rows.append(row)
            print(json.dumps(row), flush=True)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps({"meta": {
                "jax": jax.__version__, "cpu_count": os.cpu_count(),
                "machine": platform.machine(), "load_average_1min": os.getloadavg()[0],
                "import_s": round(import_s, 2), "cache_dir": str(cache),
                "cache_entries_at_start": cache_entries,
                "note": "shared machine: timings are rough"}, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
