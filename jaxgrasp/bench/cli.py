"""``python -m jaxgrasp.bench``: reproduce Tables II and III, measure speed, draw the grasps."""

import argparse
import json
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

from jaxgrasp._dask import add_scheduler_argument
from jaxgrasp._xla import add_cpu_devices
from jaxgrasp.bench.profiles import BACKENDS, PROFILES, get_profile, parse_objects
from jaxgrasp.learn.evaluate.hold import pose_noise

EPILOG = """examples:
  python -m jaxgrasp.bench --profile smoke            # CI check, a few minutes on 2 cores
  python -m jaxgrasp.bench                            # reduced run of every cell
  python -m jaxgrasp.bench --profile paper --backend mjx --chains 16
  python -m jaxgrasp.bench --objects plate,pan --out bench_out/mine --resume
  python -m jaxgrasp.bench --profile paper --backend mujoco --jobs 3
  python -m jaxgrasp.bench --profile paper --scheduler tcp://host:8786 --out /shared/b
  python -m jaxgrasp.bench --robust-tries 10          # + robust share of each cell's grasps
"""

#: Experiments run at once by default (``--jobs``): 1 until a same-window measurement shows
#: a gain (docs/design.md, "Scaling": under heavy load it did not).
DEFAULT_JOBS = 1


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m jaxgrasp.bench", description=__doc__, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", default=None, choices=sorted(PROFILES),
                   help="how much of the protocol to run (default: 'default'; with --resume "
                        "or --report-only, the profile the run in --out was made with)")
    p.add_argument("--backend", choices=BACKENDS, default=None,
                   help="physics backend of the experiments (auto: mjx on an accelerator, "
                        "mujoco on a CPU)")
    p.add_argument("--chains", type=int, default=None, help="independent chains per cell")
    p.add_argument("--iterations", type=int, default=None, help="iterations per chain")
    p.add_argument("--burn-in", type=int, default=None, help="burn-in steps per chain")
    p.add_argument("--objects", default=None,
                   help="comma-separated active-set objects (pitcher,pan,plate); a transfer "
                        "object name selects its row pair")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--checkpoint-every", type=int, default=None, metavar="STEPS",
                   help="save each experiment's chains every STEPS steps, so a killed run "
                        "resumes mid-experiment (0: only finished experiments; default: the "
                        "profile's)")
    p.add_argument("--out", type=Path, default=None,
                   help="output directory (default: bench_out/<profile>-<timestamp>, with "
                        "bench_out/latest pointing at it)")
    p.add_argument("--resume", action="store_true",
                   help="reuse finished experiments already saved in --out")
    p.add_argument("--report-only", action="store_true",
                   help="run nothing: rebuild tables and figures from the results in --out")
    p.add_argument("--robust-tries", type=int, default=None, metavar="N",
                   help="after learning, try each cell's distinct successful grasps N more "
                        "times under the pose error (--pose-error, on the cell's own trial) "
                        "and report the robust share and the distinct robust new grasps; "
                        "these trials are counted apart from the learning trials (default: "
                        "the profile's, 0: not measured)")
    p.add_argument("--pose-error", default=None, metavar="MM,DEG",
                   help="the robot's pose error: position sd (mm, per axis) and orientation "
                        "sd (degrees) (default: 3,3)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-throughput", action="store_true", help="skip the speed measurement")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--devices", type=_devices_arg, default=None, metavar="N|all",
                   help="shard each experiment's chains over N (or all) devices; the layout "
                        "is recorded in results.json (device.layout)")
    p.add_argument("--jobs", type=_jobs_arg, default=None, metavar="N",
                   help="run up to N independent experiments at once, as Dask tasks on a "
                        "local cluster of N worker processes (a transfer waits for its source, "
                        "each row's demonstrations are made once); the saved results are those "
                        "of --jobs 1, which runs them one at a time in this process (default: "
                        f"{DEFAULT_JOBS}, with --scheduler the cluster's worker count; not with "
                        "--distributed; on an accelerator each worker holds its own device "
                        "memory)")
    p.add_argument("--workers", choices=("process", "cohort"), default="process",
                   help="with --jobs N: 'process' runs each experiment in a Dask worker "
                        "process; 'cohort' runs N experiments in threads of this process, "
                        "each on its own CPU device, their trials merged into one physics call "
                        "per step (jg.learn.Cohort). Same results either way (default: "
                        "%(default)s)")
    add_scheduler_argument(p, "--out")
    p.add_argument("--distributed", action="store_true",
                   help="multi-host: call jax.distributed.initialize (JAX_COORDINATOR_ADDRESS "
                        "etc., or cluster auto-detection) and shard over every process's "
                        "devices; run the same command on every host; only process 0 writes "
                        "--out (the others write to a scratch directory)")
    return p.parse_args(argv)


def _jobs_arg(text: str) -> int:
    if text.isdigit() and int(text) >= 1:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected a positive int, got {text!r}")


def _devices_arg(text: str):
    if text == "all":
        return text
    if text.isdigit() and int(text) >= 1:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected a positive int or 'all', got {text!r}")


def _base_profile(args):
    """``--profile``; else, continuing or redrawing a run (``--resume``/``--report-only``
    with ``--out``), the profile that run was made with (its saved config, so a paper run is
    never redrawn or resumed as the default one); else the default profile."""
    if args.profile is not None:
        return get_profile(args.profile)
    previous = _previous(args.out) if args.out is not None and (
        args.resume or args.report_only) else None
    cfg = (previous or {}).get("config")
    if not cfg or cfg.get("profile") not in PROFILES:
        return get_profile("default")
    return get_profile(cfg["profile"]).with_overrides(
        objects=tuple(cfg["objects"]), transfer_sets=tuple(cfg["transfer_sets"]),
        chains=cfg["chains"], iterations=cfg["iterations"], burn_in=cfg["burn_in"],
        seed=cfg["seed"], backend=cfg.get("requested_backend", cfg.get("backend")),
        checkpoint_every=cfg["checkpoint_every"], robust_tries=cfg.get("robust_tries"),
        pose_error=tuple(cfg["pose_error"]) if cfg.get("pose_error") else None)


def _pose_error(text: str | None) -> tuple | None:
    """``--pose-error MM,DEG`` as ``(mm, degrees)`` (None: not given)."""
    if text is None:
        return None
    noise = pose_noise(text, 1)
    return (noise.position_sd * 1000.0, noise.angle_sd)


def _out_dir(args, profile) -> Path:
    if args.out is not None:
        return args.out
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("bench_out") / f"{profile.name}-{stamp}"


def _link_latest(out: Path) -> None:
    """bench_out/latest -> the newest default output directory (best effort)."""
    latest = out.parent / "latest"
    try:
        if latest.is_symlink() or not latest.exists():
            tmp = out.parent / ".latest.tmp"
            if tmp.is_symlink():
                tmp.unlink()
            tmp.symlink_to(out.name)
            tmp.replace(latest)
    except OSError:
        pass


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        profile = _base_profile(args).with_overrides(
            backend=args.backend, chains=args.chains, iterations=args.iterations,
            burn_in=args.burn_in, seed=args.seed, checkpoint_every=args.checkpoint_every,
            objects=parse_objects(args.objects) if args.objects else None,
            robust_tries=args.robust_tries, pose_error=_pose_error(args.pose_error))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    jobs = args.jobs or (None if args.scheduler else DEFAULT_JOBS)
    if args.scheduler and (args.distributed or args.workers == "cohort"):
        print("error: --scheduler runs the experiments on a Dask cluster (not with "
              "--distributed or --workers cohort)", file=sys.stderr)
        return 2
    if args.workers == "cohort" and (jobs or 1) > 1:
        if args.distributed or args.devices is not None:
            print("error: --workers cohort runs each experiment on one CPU device (no "
                  "--devices or --distributed)", file=sys.stderr)
            return 2
        add_cpu_devices(jobs)  # before JAX starts its CPU backend
    # jax loads (seconds) only once the flags are valid: --help and flag errors answer at once.
    import jax

    from jaxgrasp.mcmc import sharding

    if args.distributed and (args.jobs or 1) > 1:
        # Every process must issue the same collectives in the same order.
        print("error: --distributed runs one experiment at a time (no --jobs)", file=sys.stderr)
        return 2
    if args.distributed:
        if args.resume or args.report_only:
            print("error: --distributed runs everything from scratch on every process; "
                  "--resume/--report-only are single-process", file=sys.stderr)
            return 2
        sharding.initialize_distributed()  # before any other JAX call
        if args.devices is None:
            args.devices = "all"
    out = _out_dir(args, profile)
    previous = _previous(out)
    if previous is not None and not (args.resume or args.report_only):
        print(f"error: {out} already holds a bench run; pass --resume to continue it, "
              "--report-only to redraw it, or choose another --out", file=sys.stderr)
        return 2
    # The experiment modules load MuJoCo and the physics, after jax.distributed is initialised.
    from jaxgrasp._cache import enable_compilation_cache
    from jaxgrasp.bench import plan, report, run
    from jaxgrasp.learn.pipeline import simulator_batch
    from jaxgrasp.physics.inputs import resolve_backend

    try:
        layout = sharding.layout(sharding.chain_mesh(args.devices))
    except ValueError as err:
        print(f"error: --devices: {err}", file=sys.stderr)
        return 2
    if jax.process_index() != 0:
        # Every process computes (the chains are sharded across them); process 0 writes.
        out = Path(tempfile.mkdtemp(prefix=f"jaxgrasp-bench-p{jax.process_index()}-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.resume:
        run.remove_stale_temp_files(out)  # what a killed run was writing (never complete)
    if args.out is None and jax.process_index() == 0:
        _link_latest(out)

    # The CLI, not the library, owns process-wide JAX settings.
    enable_compilation_cache()
    backend = resolve_backend(profile.backend)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    log(f"jaxgrasp bench: profile {profile.name}, backend {backend}, {profile.chains} chains x "
        f"{profile.proposals} proposals per cell, {jobs or 'one per Dask worker'} at a time "
        f"-> {out}")

    # The run's own times, carried over from the invocations before (run.account_time: the
    # total is the experiments' seconds plus compiling each trial once, never this
    # invocation's elapsed time, so a redraw or an empty resume adds nothing).
    timings = {"total_s": 0.0, "experiments": {}}
    throughput = {}
    if previous is not None:
        prev = previous.get("timings", {})
        timings.update({k: v for k, v in prev.items() if k in ("throughput_s", "figures_s")})
        timings["robustness"] = dict(prev.get("robustness", {}))
        timings["experiments"].update(prev.get("experiments", {}))
        timings["compile_s"] = dict(prev.get("compile_s", {}))
        # Only the backend this run uses (an older bench also measured others).
        throughput.update({b: t for b, t in previous.get("throughput", {}).items()
                           if b == backend})
    sims = None
    cells = plan.plan(profile, out)
    status = "complete"
    failures = {}
    # Redrawing keeps the provenance of the run that produced the saved results.
    provenance = previous if (args.report_only and previous) else None
    if provenance:
        failures.update(previous.get("failures", {}))

    def snapshot(complete, figures=()):
        run.account_time(timings, getattr(sims, "compile_s", {}), backend)
        tbl, _ = report.collect(cells, out, timings["experiments"], profile, backend)
        res = report.build_results(profile, backend, tbl, timings, throughput, list(figures),
                                   complete, failures, provenance)
        if not provenance:
            res["device"] = dict(res["device"], layout=layout)
        report.write_outputs(out, res, profile)
        return res

    try:
        if not args.report_only:
            sims = run.Simulators(backend, simulator_batch(profile.chains, args.devices),
                                  bar=run.spinner(args.quiet))
            run.run_experiments(cells, profile, backend, sims, timings, failures,
                                resume=args.resume, quiet=args.quiet, devices=args.devices,
                                snapshot=snapshot, log=log, jobs=jobs, workers=args.workers,
                                scheduler=args.scheduler)
            run.score_robustness(cells, profile, backend, sims, timings, snapshot=snapshot,
                                 log=log)
            if not args.no_throughput:
                run.run_throughput(profile, backend, sims, timings, throughput, log)
    except KeyboardInterrupt:
        status = "interrupted"
        log(f"\ninterrupted: finished experiments are saved; continue with "
            f"--resume --out {out}")

    _, results = report.collect(cells, out, timings["experiments"], profile, backend)
    figs = []
    if not args.no_figures and results:
        t0 = time.perf_counter()
        figs = report.make_figures(out, cells, results, profile)
        timings["figures_s"] = time.perf_counter() - t0
    complete = status == "complete" and len(results) == len(cells)
    res = snapshot(complete, figs)
    report.print_summary(res, profile, out)
    if status != "complete":
        return 130
    return 0 if complete else 1


def _previous(out: Path):
    f = out / "results.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text())
    except json.JSONDecodeError:
        return {}
