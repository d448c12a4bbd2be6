"""Run the experiments of a profile (:mod:`~jaxgrasp.bench.plan`) with ``jg.learn``, saving
each one as it finishes, and time the trials.

``run_experiments(..., jobs=N)`` runs up to N independent experiments at once, as tasks on a
Dask cluster of N worker processes or on a running one (:func:`run_concurrent`), in
dependency order; each experiment has its own seed, so the saved results are those of the
one-at-a-time run (``jobs=1``).
"""

import hashlib
import json
import queue
import shutil
import sys
import threading
import time
import traceback
import uuid
from contextlib import ExitStack, contextmanager
from datetime import datetime
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxgrasp import _dask, learn, objects
from jaxgrasp._cache import enable_compilation_cache
from jaxgrasp.bench.plan import Cell, cell_seed, learn_params, load_saved, matches, physics_key
from jaxgrasp.bench.profiles import ACTIVE_METHODS, Profile
from jaxgrasp.bench.throughput import (
    MAX_ENGINE_RATIO,
    engine_limit,
    engine_ratio_valid,
    measure,
    warm_up,
)
from jaxgrasp.learn.evaluate.robustness import robustness
from jaxgrasp.learn.files.atomic import atomic_write_bytes
from jaxgrasp.learn.files.checkpoint import CheckpointMismatch
from jaxgrasp.learn.setup.demos import Demos, demo_result_arrays, demo_results_from_arrays


def progress_bar(quiet, **kw):
    """A tqdm bar on stderr (``quiet``: none)."""
    return tqdm(disable=quiet, dynamic_ncols=True, file=sys.stderr, **kw)


def spinner(quiet):
    """A progress bar for a phase of unknown length (compilation): shows elapsed time."""
    @contextmanager
    def bar(desc):
        b = progress_bar(quiet, total=1, desc=desc, bar_format="{desc}: {elapsed} {postfix}")
        try:
            yield b
        finally:
            b.update(1)
            b.close()

    return bar


def set_aside(cell: Cell) -> Path | None:
    """Move a saved result of another configuration out of the way (``runs/.stale/...``)
    before its cell runs again; returns where it went."""
    if not cell.path.exists():
        return None
    runs = next(p for p in cell.path.parents if p.name == "runs")
    dest = runs / ".stale" / datetime.now().strftime("%Y%m%d-%H%M%S-%f") / cell.path.relative_to(
        runs)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(str(cell.path), str(dest))
    return dest


class KeyedLocks:
    """One lock per key (created on first use): ``with locks(key): ...``."""

    def __init__(self):
        self._guard, self._locks = threading.Lock(), {}

    def __call__(self, key) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(key, threading.Lock())


#: Demonstration files being computed: experiments in threads of one process compute them
#: once (the others wait and read the file). Across worker processes the scheduler does it
#: (:func:`run_concurrent` starts a row's other cells once its first has the demos).
_DEMO_LOCKS = KeyedLocks()


class Simulators:
    """One compiled trial per (object, backend), shared by every cell on it: same chains =>
    same batch shape, so the physics compiles once per object, not once per experiment.
    ``compile_s`` records the compile time of each (measured apart from the experiments).

    Thread-safe: concurrent experiments (``jobs > 1``) asking for the same object wait for
    one compilation."""

    def __init__(self, backend: str, chains: int, bar=None):
        self.backend, self.chains, self._sims, self.compile_s = backend, chains, {}, {}
        self.bar = bar  # callable(desc) -> context manager progress bar, or None
        self._locks = KeyedLocks()
        self.cohort = None  # set by a cohort run: every trial's calls go through it

    def attach(self, cohort):
        """Route every trial's host calls (those made so far and later) through ``cohort``
        (a ``jg.learn.Cohort``), or back to direct calls (None)."""
        self.cohort = cohort
        for sim in self._sims.values():
            sim.cohort = cohort

    def __call__(self, name: str, backend: str | None = None):
        key = (name, backend or self.backend)
        if key in self._sims:
            return self._sims[key]
        with self._locks(key):
            if key not in self._sims:
                sim = learn.Simulator(objects.load(name), backend=key[1],
                                      batch_size=self.chains)
                sim.cohort = self.cohort
                if self.bar is not None:
                    with self.bar(f"compile {key[1]} trial: {name}"):
                        self.compile_s[key] = warm_up(sim)
                else:
                    self.compile_s[key] = warm_up(sim)
                self._sims[key] = sim
        return self._sims[key]


def needs_demos(cell: Cell) -> bool:
    """Whether the cell's workflow makes demonstrations on its own object."""
    return cell.table == "active" or cell.column == "target"


def cell_demos(cell: Cell, profile: Profile, backend: str, sims: Simulators, on_ready=None):
    """The cell's demonstrations, computed once per (object, seed, params, backend) and
    saved under ``runs/demos/`` so every cell on that object (and ``--resume``) reuses them.

    Same arguments as the workflow's own ``demonstrations`` call, so the chains are the same
    as without the cache. Raises the ValueError of ``demonstrations`` when none succeeds.
    Concurrent calls for the same file compute it once (a lock per file); ``on_ready()`` is
    called once the demonstrations are there.
    """
    sim = sims(cell.obj)
    params = learn_params(profile)
    seed = cell_seed(profile.seed, cell.row_id)
    config = {"object": cell.obj, "object_hash": sim.obj.content_hash, "seed": seed,
              "backend": backend, "params": params.to_dict()}
    if sim.scene is not None:  # gripper and protocol: new physics must not reuse old demos
        config["physics"] = repr((sim.scene.gripper, sim.scene.params))
    digest = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode())
    runs = next(p for p in cell.path.parents if p.name == "runs")
    path = runs / "demos" / cell.obj / f"seed{seed}-{digest.hexdigest()[:16]}.npz"
    with _DEMO_LOCKS(str(path.resolve())):
        if path.is_file():
            with np.load(path) as z:
                arrays = dict(z)
            demos = Demos(arrays.pop("poses"), demo_results_from_arrays(arrays),
                          arrays.pop("spares", None))
        else:
            demos = learn.demonstrations(sim.obj, num=params.num_demos, seed=seed, trial=sim,
                                         params=params)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, poses=np.asarray(demos.poses), spares=demos.spares,
                     **demo_result_arrays(demos.results))
            tmp.replace(path)  # atomic: a killed run never leaves half a file
            atomic_write_bytes(path.with_suffix(".json"),
                               json.dumps(config, indent=1, default=str).encode())
    if on_ready is not None:
        on_ready()
    return demos


def run_cell(cell: Cell, profile: Profile, backend: str, sims: Simulators, source_result=None,
             progress=False, devices=None, on_demos=None):
    """Run one experiment with ``jg.learn`` and return its LearnResult (not yet saved).
    ``on_demos()``: called once the cell's demonstrations are ready (cells that make some)."""
    sim = sims(cell.obj)
    common = dict(chains=profile.chains, iterations=profile.iterations,
                  burn_in=profile.burn_in, seed=cell_seed(profile.seed, cell.row_id),
                  params=learn_params(profile), backend=backend, trial=sim, progress=progress,
                  devices=devices)
    if profile.checkpoint_every:
        # Long profiles: a killed experiment resumes from its last checkpoint.
        common.update(checkpoint_dir=cell.path / "checkpoint",
                      checkpoint_every=profile.checkpoint_every)

    def run():
        if cell.table == "active":
            method, sketch = ACTIVE_METHODS[cell.column]
            return learn.active(sim.obj, method=method, sketch=sketch,
                                demos=cell_demos(cell, profile, backend, sims, on_demos),
                                **common)
        demos = cell_demos(cell, profile, backend, sims, on_demos) if needs_demos(cell) else None
        return learn.transfer(source_result, sim.obj, modes=cell.column, demos=demos, **common)

    try:
        return run()
    except CheckpointMismatch:
        set_aside(cell)  # a killed run of another configuration: keep it, start afresh
        return run()


def score_robustness(cells, profile, backend, sims, timings, *, snapshot, log) -> list:
    """Try the distinct successful grasps of every saved cell of this configuration under
    ``profile.noise`` (``jg.learn.robustness`` on the cell's own trial, seeded by the cell's
    seed) and save the result with its measurement; a cell already measured under this noise
    is left as it is (``--resume``). Each cell's seconds go to ``timings["robustness"]``, apart
    from the experiments'. Returns the ids of the cells measured now."""
    noise = profile.noise
    if noise is None:
        return []
    done = []
    for c in cells:
        result = load_saved(c)
        if (result is None or not matches(result, c, profile, backend)
                or (result.robustness is not None and result.robustness.noise == noise)):
            continue
        t0 = time.perf_counter()
        rob = robustness(result, trial=sims(c.obj), noise=noise, seed=result.seed,
                         stop_early=True)
        result.with_robustness(rob).save(c.path)
        timings.setdefault("robustness", {})[c.id] = time.perf_counter() - t0
        log(f"  {c.id}: robust share {rob.robust_share:.2f} of {len(rob.held)} distinct "
            f"successful grasps ({rob.num_trials} trials under {noise.label})")
        done.append(c.id)
        snapshot(False)
    return done


def remove_stale_temp_files(out: Path) -> list:
    """Delete the temp files a killed run left under ``out`` (the atomic writers'
    ``.<name>.*.tmp`` and the demos' ``*.tmp.npz``: never complete, never read); returns them.
    Only for a directory no other process is writing to (``--resume``)."""
    stale = [p for p in Path(out).rglob(".*.tmp") if p.is_file()]
    stale += [p for p in Path(out).rglob("*.tmp.npz") if p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def run_experiments(cells, profile, backend, sims, timings, failures, *, resume, quiet, devices,
                    snapshot, log, jobs=1, workers="process", scheduler=None):
    """Run every cell without a matching saved result (``resume``: reuse those), saving each
    as it finishes; a failed cell is recorded in ``failures`` and skips its dependants.
    ``jobs > 1`` or a Dask ``scheduler``: up to ``jobs`` cells at once in ``workers``
    (:func:`run_concurrent`), same results."""
    todo = []
    for c in cells:
        saved = load_saved(c) if resume else None
        if saved is not None and matches(saved, c, profile, backend):
            continue
        if saved is not None or (c.path.exists() and not resume):
            log(f"{c.id}: saved result has another configuration, moved to "
                f"{set_aside(c)}; running it again")
        # No result yet: a killed experiment's checkpoint stays and run_cell continues it.
        todo.append(c)
    if len(todo) < len(cells):
        log(f"resuming: {len(cells) - len(todo)} of {len(cells)} experiments already done")
    if ((jobs or 1) > 1 or scheduler) and todo:
        return run_concurrent(todo, profile, backend, sims, timings, failures, jobs=jobs,
                              quiet=quiet, devices=devices, snapshot=snapshot, workers=workers,
                              scheduler=scheduler)
    demo_failed = {}
    bar = progress_bar(quiet, total=len(todo), unit="exp", desc="experiments")
    with bar:
        for c in todo:
            bar.set_postfix_str(c.id)
            skip = _skip_reason(c, failures, demo_failed)
            if skip:
                failures[c.id] = skip
                bar.update(1)
                continue
            source = load_saved(c.source) if c.source is not None else None
            sims(c.obj)  # compile the object's trial first: its time is reported apart
            t0 = time.perf_counter()
            try:
                result = run_cell(c, profile, backend, sims, source_result=source,
                                  progress=not quiet, devices=devices)
            except ValueError as err:
                # A workflow that cannot run here (e.g. no demonstration succeeded) is
                # reported in the results; the other experiments still run.
                _record_failure(c, err, failures, demo_failed, bar, snapshot)
                continue
            _record_result(c, result, time.perf_counter() - t0, timings, bar, quiet, snapshot)


def _skip_reason(c, failures, demo_failed):
    """Why ``c`` is not run (its source failed, or its row's demonstrations did), or None."""
    if c.source is not None and c.source.id in failures:
        return f"skipped: its source {c.source.id} failed"
    if c.table == "active" and c.row_id in demo_failed:
        # Same object and seed => the same demonstrations: they would fail again.
        return f"skipped: demonstrations failed in {demo_failed[c.row_id]}"
    return None


def _record_failure(c, err, failures, demo_failed, bar, snapshot):
    failures[c.id] = f"{type(err).__name__}: {err}"
    if "demonstrat" in str(err):
        demo_failed[c.row_id] = c.id
    bar.write(f"  {c.id}: FAILED: {failures[c.id]}", file=sys.stderr)
    snapshot(False)
    bar.update(1)


def _record_result(c, result, seconds, timings, bar, quiet, snapshot):
    # Save first: a finished experiment is never lost, tables come from disk.
    result.info["physics"] = physics_key()
    result.save(c.path)
    timings["experiments"][c.id] = seconds
    snapshot(False)
    bar.update(1)
    if not quiet:
        tot = result.counts.sum(axis=0).tolist()
        bar.write(f"  {c.id}: success/slipped/collision/miss = {tot} over "
                  f"{result.num_chains} chains ({seconds:.1f} s)", file=sys.stderr)


def run_concurrent(todo, profile, backend, sims, timings, failures, *, jobs, quiet, devices,
                   snapshot, workers="process", scheduler=None):
    """Run the cells ``todo`` (in plan order) up to ``jobs`` at a time.

    A cell starts once what it depends on is done: a transfer cell after its source cell
    (saved or failed), and a cell whose demonstrations another cell of its row makes (the
    row's first such cell in plan order, its *owner*) once the owner has them or has
    finished. So the demonstrations are computed once, by the cell that computes them when
    run one at a time, and a row whose demonstrations fail skips its other cells as the
    sequential run does. Each cell has its own seed (:func:`plan.cell_seed`), so the results
    do not depend on ``jobs``; only the order in which cells finish and the timings do.

    ``workers="cohort"``: up to ``jobs`` cells run in threads of this process, each on its
    own CPU device, and their trial calls are merged into one host call per step
    (:class:`jaxgrasp.learn.Cohort`; needs ``jobs + 1`` CPU devices). Trials are independent
    per row, so the results are again those of the one-at-a-time run.

    ``workers="process"`` (the bench): each cell is a Dask task (:mod:`jaxgrasp._dask`) on a
    local cluster of ``jobs`` single-threaded worker processes, or on the running cluster at
    ``scheduler`` (``jobs`` None: as many cells at once as it has workers). A worker process
    keeps its compiled trials for its next cells and shares the persistent compilation cache;
    it never runs two cells at once. Threads of one process would share the GIL and XLA's CPU
    thread pool, and a sampler's host callback runs a second (the trial's) XLA computation
    from inside a pool thread: with two cells' callbacks holding both workers of a 2-thread
    pool, neither trial can run. ``workers="thread"`` runs ``run_cell`` in threads of this
    process: only for a ``run_cell`` that starts no nested XLA computation (tests replace it
    by a fake).

    This thread starts the cells and does all bookkeeping (saves each result as soon as its
    cell finishes, updates ``timings``, ``failures`` and ``snapshot``); workers only compute.
    A ValueError of a cell, or the loss of its worker (:class:`WorkerLost`, after Dask's
    retries), is recorded as its failure (the others go on); any other exception is raised
    here once it arrives. An interrupt (Ctrl-C) is raised here at once and stops the workers.
    """
    by_id = {c.id: c for c in todo}
    pending = list(todo)
    running, finished, demos_ready, demo_failed = {}, set(), set(), {}
    owner = {}
    for c in todo:
        if needs_demos(c):
            owner.setdefault(c.row_id, c.id)

    def ready(c):
        if c.source is not None and c.source.id in by_id and c.source.id not in finished:
            return False
        if needs_demos(c) and owner[c.row_id] != c.id:
            return c.row_id in demos_ready or owner[c.row_id] in finished
        return True

    if workers == "process":
        pool = _DaskWorkers(jobs, profile, backend, sims, devices, scheduler)
        jobs = pool.jobs
    else:
        pool = {"thread": _ThreadWorkers, "cohort": _CohortWorkers}[workers](
            jobs, profile, backend, sims, devices)
    bar = progress_bar(quiet, total=len(todo), unit="exp", desc=f"experiments ({jobs} jobs)")
    try:
        with bar:
            while pending or running:
                while len(running) < jobs:
                    c = next((c for c in pending if ready(c)), None)
                    if c is None:
                        break
                    pending.remove(c)
                    skip = _skip_reason(c, failures, demo_failed)
                    if skip:
                        failures[c.id] = skip
                        finished.add(c.id)
                        bar.update(1)
                        continue
                    running[c.id] = c
                    pool.start(c)
                if not running:
                    if not pending:  # the last cells were skipped
                        break
                    # every pending cell waits for one that will never finish
                    raise RuntimeError(f"no cell can start: {[c.id for c in pending]}")
                bar.set_postfix_str(", ".join(running))
                kind, cid, *rest = pool.next_event()
                c = by_id[cid]
                if kind == "demos":
                    demos_ready.add(c.row_id)
                    continue
                result, err, seconds = rest
                del running[cid]
                finished.add(cid)
                if isinstance(err, ValueError | WorkerLost):
                    _record_failure(c, err, failures, demo_failed, bar, snapshot)
                elif err is not None:
                    raise err
                else:
                    _record_result(c, result, seconds, timings, bar, quiet, snapshot)
    except BaseException:
        pool.close(wait=False)  # an interrupt or error: stop the workers now
        raise
    pool.close()
    if workers == "cohort":
        timings["merged_calls"] = merged_summary(pool.cohort.sizes)


def merged_summary(sizes) -> dict:
    """A cohort's merged host calls (``{trials: count}``): how many, trials per call, and
    the share of calls carrying >= 64 trials."""
    calls = sum(sizes.values())
    trials = sum(n * k for n, k in sizes.items())
    big = sum(k for n, k in sizes.items() if n >= 64)
    return dict(calls=int(calls), trials=int(trials),
                trials_per_call=float(trials / calls) if calls else 0.0,
                share_ge_64=float(big / calls) if calls else 0.0,
                sizes={str(n): int(k) for n, k in sorted(sizes.items())})


def _work(c, profile, backend, sims, devices, events):
    """Run cell ``c``; put ``("demos", id)`` when its demonstrations are there and
    ``("done", id, result, error, seconds)`` at the end (never raises)."""
    try:
        source = load_saved(c.source) if c.source is not None else None
        sims(c.obj)  # compile the object's trial first: its time is reported apart
        t0 = time.perf_counter()
        result = run_cell(c, profile, backend, sims, source_result=source, progress=False,
                          devices=devices, on_demos=lambda: events.put(("demos", c.id)))
        return ("done", c.id, result, None, time.perf_counter() - t0)
    except Exception as err:  # noqa: BLE001 - handed to the scheduler
        return ("done", c.id, None, err, None)


class _ThreadWorkers:
    """``run_cell`` in daemon threads of this process (see :func:`run_concurrent`)."""

    def __init__(self, jobs, profile, backend, sims, devices):
        self.args = (profile, backend, sims, devices)
        self.events = queue.Queue()

    def start(self, c):
        def target():
            self.events.put(_work(c, *self.args, self.events))

        threading.Thread(target=target, name=f"bench {c.id}", daemon=True).start()

    def next_event(self):
        return self.events.get()

    def close(self, wait=True):
        pass


class _CohortWorkers(_ThreadWorkers):
    """``run_cell`` in threads of this process, merged by a ``jg.learn.Cohort`` (see
    :func:`run_concurrent`); ``cohort`` keeps the merged calls' statistics."""

    def __init__(self, jobs, profile, backend, sims, devices):
        super().__init__(jobs, profile, backend, sims, devices)
        self.sims, self.cohort = sims, learn.Cohort(jobs)
        sims.attach(self.cohort)

    def start(self, c):
        def target():
            with self.cohort.member():
                ev = _work(c, *self.args, self.events)
            self.events.put(ev)

        threading.Thread(target=target, name=f"bench {c.id}", daemon=True).start()

    def close(self, wait=True):
        self.sims.attach(None)  # later calls (the throughput) run directly


class WorkerLost(Exception):
    """A cell's task could not finish on the cluster (its worker died each time Dask tried,
    or the cluster went away): recorded as the cell's failure; a ``--resume`` runs it again."""


class _DaskWorkers:
    """Each cell a task on a Dask cluster (see :func:`run_concurrent`): a local one of ``jobs``
    single-threaded worker processes, or the running one at ``scheduler`` (then ``jobs`` is
    at most its worker count, by default all of them)."""

    def __init__(self, jobs, profile, backend, sims, devices, scheduler=None):
        self.events, self.sims = queue.Queue(), sims
        # The run's own event topic: the "demos" signals of its cells, none of another client's
        self.topic = f"jaxgrasp-bench-{uuid.uuid4().hex}"
        with ExitStack() as stack:  # closed here only if the cluster cannot be used
            self.client = stack.enter_context(_dask.client(scheduler, jobs))
            self.client.subscribe_topic(self.topic,
                                        lambda event: self.events.put(tuple(event[1])))
            self.jobs = jobs or max(1, len(self.client.nthreads()))
            self._stack = stack.pop_all()
        self.args = (profile, backend, sims.chains, devices, jax.config.jax_compilation_cache_dir,
                     self.topic)

    def start(self, c):
        future = self.client.submit(_dask_cell, c, *self.args, key=f"{self.topic} {c.id}",
                                    pure=False)
        future.add_done_callback(lambda f: self.events.put(("done", c.id, f)))

    def next_event(self):
        ev = self.events.get()
        if ev[0] != "done":
            return ev
        try:
            result, err, seconds, compile_s = ev[2].result()
        except Exception as e:  # noqa: BLE001 - e.g. KilledWorker: the worker died running it
            return "done", ev[1], None, WorkerLost(f"{type(e).__name__}: {e}"), None
        for key, s in compile_s.items():
            self.sims.compile_s.setdefault(key, s)
        if err is not None:
            name, msg, tb = err
            err = ValueError(msg) if name == "ValueError" else RuntimeError(
                f"{name}: {msg} (in a bench worker)\n{tb}")
        return "done", ev[1], result, err, seconds

    def close(self, wait=True):
        """Close the client, and the local cluster with its workers (busy ones too)."""
        self._stack.close()


#: The compiled trials of this worker process, per (backend, batch): kept for its next cells.
_WORKER_SIMS = {}


def _dask_cell(c, profile, backend, chains, devices, cache, topic):
    """A Dask task: run cell ``c`` in this worker process, one cell at a time per process,
    signalling ``("demos", id)`` on ``topic`` once its demonstrations are there. Returns
    ``(result, error, seconds, compile_s)``, the error as ``(type name, message, traceback)``
    (any exception survives the trip)."""
    # Only ever called in a Dask worker
    from distributed import get_worker

    worker = get_worker()

    class Events:
        def put(self, event):
            worker.log_event(topic, list(event))

    with _dask.ONE_AT_A_TIME:
        if cache:
            enable_compilation_cache(cache)
        sims = _WORKER_SIMS.setdefault((backend, chains), Simulators(backend, chains))
        _, _, result, err, seconds = _work(c, profile, backend, sims, devices, Events())
    if err is not None:
        err = (type(err).__name__, str(err),
               "".join(traceback.format_exception(type(err), err, err.__traceback__)))
    return result, err, seconds, dict(sims.compile_s)


def run_throughput(profile, backend, sims, timings, throughput, log):
    """trials/s of the run's backend ``backend`` (only that one: a bench run measures the
    physics it used, nothing it did not) on the experiments' compiled trial of the profile's
    first object; compile time apart."""
    obj = profile.objects[0]
    t0 = time.perf_counter()
    for b in [k for k in throughput if k != backend]:
        del throughput[b]  # another backend's figures (an older run's) are not this run's
    rec = {"backend": backend, "object": obj}
    try:
        sim = sims(obj, backend)
    except Exception as err:  # noqa: BLE001 - any failure means "not available here"
        throughput[backend] = dict(rec, available=False, error=f"{type(err).__name__}: {err}")
        log(f"throughput: backend {backend} unavailable ({throughput[backend]['error']})")
    else:
        rec.update(available=True, compile_s=sims.compile_s[(obj, backend)])
        rec.update(measure(sim, seconds=profile.throughput_seconds, seed=profile.seed))
        limit = engine_limit(sim, seconds=profile.throughput_seconds / 2, seed=profile.seed)
        if limit:  # how close the full trial runs to the C engine's own rollout speed
            ratio = rec["trials_per_s"] / limit["rollout_trials_per_s"]
            rec.update(limit, engine_ratio=ratio, engine_ratio_valid=engine_ratio_valid(ratio))
            if not rec["engine_ratio_valid"]:
                log(f"throughput: full trial at {ratio:.2f}x its rollout alone, above the "
                    f"physical limit ({MAX_ENGINE_RATIO}): a measurement error (noisy machine)")
        if timings["experiments"]:
            # Chain steps per second of the experiments themselves (demos, sketches and the
            # samplers' compilation included).
            spent = sum(timings["experiments"].values())
            rec["chain_steps_per_s"] = (len(timings["experiments"]) * profile.chains
                                        * profile.proposals / spent)
        throughput[backend] = rec
    timings["throughput_s"] = time.perf_counter() - t0


def account_time(timings: dict, compile_s: dict, backend: str) -> dict:
    """Set ``timings``' totals from the run's own work, each piece counted once.

    ``experiments``: each experiment's own seconds, recorded by the invocation that ran it
    (a resume adds only the experiments it runs; a rerun of one replaces its time).
    ``compile_s`` (``{(object, backend): s}``, e.g. ``Simulators.compile_s``) is merged into
    ``timings["compile_s"]`` keeping the first time recorded per trial, so a resume's or a
    throughput measurement's recompilation of a trial is not counted again. Then

    - ``experiments_s`` = the sum of ``experiments``;
    - ``setup_s`` = the compile times of the trials on ``backend`` (the run's);
    - ``total_s`` = ``experiments_s + setup_s``.

    Not counted: starting Python and JAX, the throughput measurement (``throughput_s``),
    the robustness of the cells' grasps (``robustness``, each cell's seconds, and their sum
    ``robustness_s``), figures (``figures_s``) and writing the reports; so a
    ``--report-only`` redraw, or a ``--resume`` with nothing left to run, leaves ``total_s``
    as it was. With ``--jobs`` > 1
    experiments overlap: the total is then the work's time, more than the elapsed time.
    """
    merged = timings.setdefault("compile_s", {})
    for (obj, b), s in compile_s.items():
        merged.setdefault(f"{b}/{obj}", float(s))
    timings["experiments_s"] = float(sum(timings["experiments"].values()))
    timings["setup_s"] = float(sum(s for k, s in merged.items()
                                   if k.split("/", 1)[0] == backend))
    timings["total_s"] = timings["experiments_s"] + timings["setup_s"]
    if timings.get("robustness"):  # scoring grasps after learning: reported apart
        timings["robustness_s"] = float(sum(timings["robustness"].values()))
    return timings
