"""``python -m jaxgrasp.bench``: reproduce Tables II and III, measure speed, draw the grasps."""

import argparse
import json
import sys
import time
from datetime import datetime
from pathlib import Path

from jaxgrasp.bench import run as R
from jaxgrasp.bench.profiles import BACKENDS, PROFILES, get_profile, parse_objects

EPILOG = """examples:
  python -m jaxgrasp.bench --profile smoke            # CI check, a few minutes on 2 cores
  python -m jaxgrasp.bench                            # reduced run of every cell
  python -m jaxgrasp.bench --profile paper --backend mjx --chains 16
  python -m jaxgrasp.bench --objects plate,pan --out bench_out/mine --resume
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m jaxgrasp.bench", description=__doc__, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", default="default", choices=sorted(PROFILES),
                   help="how much of the protocol to run (default: %(default)s)")
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
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-throughput", action="store_true", help="skip the speed measurement")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--devices", type=_devices_arg, default=None, metavar="N|all",
                   help="shard each experiment's chains over N (or all) devices; the layout "
                        "is recorded in results.json (device.layout)")
    p.add_argument("--distributed", action="store_true",
                   help="multi-host: call jax.distributed.initialize (JAX_COORDINATOR_ADDRESS "
                        "etc., or cluster auto-detection) and shard over every process's "
                        "devices; run the same command on every host; only process 0 writes "
                        "--out (the others write to a scratch directory)")
    return p.parse_args(argv)


def _devices_arg(text: str):
    if text == "all":
        return text
    if text.isdigit() and int(text) >= 1:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected a positive int or 'all', got {text!r}")


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


def _bar(quiet, **kw):
    from tqdm.auto import tqdm

    return tqdm(disable=quiet, dynamic_ncols=True, file=sys.stderr, **kw)


def _spinner(quiet):
    """A progress bar for a phase of unknown length (compilation): shows elapsed time."""
    from contextlib import contextmanager

    @contextmanager
    def bar(desc):
        b = _bar(quiet, total=1, desc=desc, bar_format="{desc}: {elapsed} {postfix}")
        try:
            yield b
        finally:
            b.update(1)
            b.close()

    return bar


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        profile = get_profile(args.profile).with_overrides(
            backend=args.backend, chains=args.chains, iterations=args.iterations,
            burn_in=args.burn_in, seed=args.seed, checkpoint_every=args.checkpoint_every,
            objects=parse_objects(args.objects) if args.objects else None)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.distributed:
        if args.resume or args.report_only:
            print("error: --distributed runs everything from scratch on every process; "
                  "--resume/--report-only are single-process", file=sys.stderr)
            return 2
        from jaxgrasp.mcmc import sharding

        sharding.initialize_distributed()  # before any other JAX call
        if args.devices is None:
            args.devices = "all"
    out = _out_dir(args, profile)
    previous = _previous(out)
    if previous is not None and not (args.resume or args.report_only):
        print(f"error: {out} already holds a bench run; pass --resume to continue it, "
              "--report-only to redraw it, or choose another --out", file=sys.stderr)
        return 2
    import jax

    from jaxgrasp.mcmc import sharding

    try:
        layout = sharding.layout(sharding.chain_mesh(args.devices))
    except ValueError as err:
        print(f"error: --devices: {err}", file=sys.stderr)
        return 2
    if jax.process_index() != 0:
        # Every process computes (the chains are sharded across them); process 0 writes.
        import tempfile

        out = Path(tempfile.mkdtemp(prefix=f"jaxgrasp-bench-p{jax.process_index()}-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.resume:
        R.remove_stale_temp_files(out)  # what a killed run was writing (never complete)
    if args.out is None and jax.process_index() == 0:
        _link_latest(out)

    import jaxgrasp

    # The CLI, not the library, owns process-wide JAX settings.
    jaxgrasp.enable_compilation_cache()
    backend = R.resolve_backend(profile.backend)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    log(f"jaxgrasp bench: profile {profile.name}, backend {backend}, {profile.chains} chains x "
        f"{profile.proposals} proposals per cell -> {out}")

    t_start = time.perf_counter()
    timings = {"total_s": 0.0, "experiments": {}}
    throughput = {}
    if previous is not None:
        timings["experiments"].update(previous.get("timings", {}).get("experiments", {}))
        throughput.update(previous.get("throughput", {}))
    prior_total = previous.get("timings", {}).get("total_s", 0.0) if previous else 0.0
    cells = R.plan(profile, out)
    status = "complete"
    failures = {}
    # Redrawing keeps the provenance of the run that produced the saved results.
    provenance = previous if (args.report_only and previous) else None
    if provenance:
        failures.update(previous.get("failures", {}))

    def snapshot(complete, figures=()):
        timings["total_s"] = prior_total + time.perf_counter() - t_start
        tbl, _ = R.collect(cells, out, timings["experiments"], profile, backend)
        res = R.build_results(profile, backend, tbl, timings, throughput, list(figures),
                              complete, failures, provenance)
        if not provenance:
            res["device"] = dict(res["device"], layout=layout)
        R.write_outputs(out, res, profile)
        return res

    try:
        if not args.report_only:
            from jaxgrasp.learn.active_learning import simulator_batch

            sims = R.Simulators(backend, simulator_batch(profile.chains, args.devices),
                                bar=_spinner(args.quiet))
            _run_experiments(cells, profile, backend, sims, out, timings, failures, args,
                             snapshot, log)
            if not args.no_throughput:
                _run_throughput(profile, backend, sims, timings, throughput, log)
    except KeyboardInterrupt:
        status = "interrupted"
        log(f"\ninterrupted: finished experiments are saved; continue with "
            f"--resume --out {out}")

    _, results = R.collect(cells, out, timings["experiments"], profile, backend)
    figs = []
    if not args.no_figures and results:
        from jaxgrasp.bench.report import make_figures

        t0 = time.perf_counter()
        figs = make_figures(out, cells, results, profile)
        timings["figures_s"] = time.perf_counter() - t0
    complete = status == "complete" and len(results) == len(cells)
    res = snapshot(complete, figs)
    _print_summary(res, profile, out)
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


def _run_experiments(cells, profile, backend, sims, out, timings, failures, args, snapshot,
                     log):
    todo = []
    for c in cells:
        saved = R.load_saved(c) if args.resume else None
        if saved is not None and R.matches(saved, c, profile, backend):
            continue
        if saved is not None or (c.path.exists() and not args.resume):
            log(f"{c.id}: saved result has another configuration, moved to "
                f"{R.set_aside(c)}; running it again")
        # No result yet: a killed experiment's checkpoint stays and run_cell continues it.
        todo.append(c)
    if len(todo) < len(cells):
        log(f"resuming: {len(cells) - len(todo)} of {len(cells)} experiments already done")
    demo_failed = {}
    bar = _bar(args.quiet, total=len(todo), unit="exp", desc="experiments")
    with bar:
        for c in todo:
            bar.set_postfix_str(c.id)
            skip = None
            if c.source is not None and c.source.id in failures:
                skip = f"skipped: its source {c.source.id} failed"
            elif c.table == "active" and c.row_id in demo_failed:
                # Same object and seed => the same demonstrations: they would fail again.
                skip = f"skipped: demonstrations failed in {demo_failed[c.row_id]}"
            if skip:
                failures[c.id] = skip
                bar.update(1)
                continue
            source = R.load_saved(c.source) if c.source is not None else None
            sims(c.obj)  # compile the object's trial first: its time is reported apart
            t0 = time.perf_counter()
            try:
                result = R.run_cell(c, profile, backend, sims, source_result=source,
                                    progress=not args.quiet, devices=args.devices)
            except ValueError as err:
                # A workflow that cannot run here (e.g. no demonstration succeeded) is
                # reported in the results; the other experiments still run.
                failures[c.id] = f"{type(err).__name__}: {err}"
                if "demonstrat" in str(err):
                    demo_failed[c.row_id] = c.id
                bar.write(f"  {c.id}: FAILED: {failures[c.id]}", file=sys.stderr)
                snapshot(False)
                bar.update(1)
                continue
            # Save first: a finished experiment is never lost, tables come from disk.
            result.info["physics"] = R.physics_key()
            result.save(c.path)
            timings["experiments"][c.id] = time.perf_counter() - t0
            snapshot(False)
            bar.update(1)
            if not args.quiet:
                tot = result.counts.sum(axis=0).tolist()
                bar.write(f"  {c.id}: success/slipped/collision/miss = {tot} over "
                          f"{result.num_chains} chains ({timings['experiments'][c.id]:.1f} s)",
                          file=sys.stderr)


def _run_throughput(profile, backend, sims, timings, throughput, log):
    """trials/s per backend on the experiments' compiled trials; compile time apart."""
    from jaxgrasp.bench.throughput import measure

    backends = []
    for b in profile.throughput_backends:
        b = backend if b == "auto" else b
        if b not in backends:
            backends.append(b)
    obj = profile.objects[0]
    t0 = time.perf_counter()
    for b in backends:
        rec = {"backend": b, "object": obj}
        try:
            sim = sims(obj, b)
        except Exception as err:  # noqa: BLE001 - any failure means "not available here"
            throughput[b] = dict(rec, available=False, error=f"{type(err).__name__}: {err}")
            log(f"throughput: backend {b} unavailable ({throughput[b]['error']})")
            continue
        rec.update(available=True, compile_s=sims.compile_s[(obj, b)])
        rec.update(measure(sim, seconds=profile.throughput_seconds, seed=profile.seed))
        if b == backend and timings["experiments"]:
            # Chain steps per second of the experiments themselves (demos, sketches and the
            # samplers' compilation included).
            spent = sum(timings["experiments"].values())
            rec["chain_steps_per_s"] = (len(timings["experiments"]) * profile.chains
                                        * profile.proposals / spent)
        throughput[b] = rec
    timings["throughput_s"] = time.perf_counter() - t0
    timings["compile_s"] = {f"{b}/{o}": s for (o, b), s in sims.compile_s.items()}


def _print_summary(res, profile, out):
    from jaxgrasp.bench import tables

    print()
    print(R.render_tables(res["tables"], profile, markdown=False))
    if res["tables"]["active"] or res["tables"]["transfer"]:
        print()
        print("Learned grasps (successes include re-proposed demonstrations):")
        print(tables.render_learned(res["tables"], markdown=False))
    print()
    print(tables.render_claims_text(res["comparison"]["claims"]))
    if res["throughput"]:
        print()
        print("Throughput")
        print(R.render_throughput(res["throughput"], markdown=False))
    if res.get("failures"):
        print()
        print("FAILED experiments (not in the tables):")
        for k, v in res["failures"].items():
            print(f"  {k}: {v}")
    print()
    print(f"Wrote {out}/results.json, tables.md, tables.csv"
          + (f" and {len(res['figures'])} figures in {out}/figures" if res["figures"] else "")
          + f" ({res['timings']['total_s']:.1f} s).")
