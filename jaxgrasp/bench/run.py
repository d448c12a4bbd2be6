"""Run the experiments of a profile (:mod:`~jaxgrasp.bench.plan`) with ``jg.learn``, saving
each one as it finishes, and time the trials."""

import hashlib
import json
import shutil
import sys
import time
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from jaxgrasp import learn, objects
from jaxgrasp.bench.plan import Cell, cell_seed, learn_params, load_saved, matches, physics_key
from jaxgrasp.bench.profiles import ACTIVE_METHODS, Profile
from jaxgrasp.bench.throughput import measure, warm_up
from jaxgrasp.learn.checkpoint import CheckpointMismatch
from jaxgrasp.learn.demos import Demos, demo_result_arrays, demo_results_from_arrays
from jaxgrasp.learn.files import atomic_write_bytes


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


class Simulators:
    """One compiled trial per (object, backend), shared by every cell on it: same chains =>
    same batch shape, so the physics compiles once per object, not once per experiment.
    ``compile_s`` records the compile time of each (measured apart from the experiments)."""

    def __init__(self, backend: str, chains: int, bar=None):
        self.backend, self.chains, self._sims, self.compile_s = backend, chains, {}, {}
        self.bar = bar  # callable(desc) -> context manager progress bar, or None

    def __call__(self, name: str, backend: str | None = None):
        key = (name, backend or self.backend)
        if key not in self._sims:
            sim = learn.Simulator(objects.load(name), backend=key[1], batch_size=self.chains)
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


def cell_demos(cell: Cell, profile: Profile, backend: str, sims: Simulators):
    """The cell's demonstrations, computed once per (object, seed, params, backend) and
    saved under ``runs/demos/`` so every cell on that object (and ``--resume``) reuses them.

    Same arguments as the workflow's own ``demonstrations`` call, so the chains are the same
    as without the cache. Raises the ValueError of ``demonstrations`` when none succeeds.
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
    if path.is_file():
        with np.load(path) as z:
            arrays = dict(z)
        return Demos(arrays.pop("poses"), demo_results_from_arrays(arrays))
    demos = learn.demonstrations(sim.obj, num=params.num_demos, seed=seed, trial=sim,
                                 params=params)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, poses=np.asarray(demos.poses), **demo_result_arrays(demos.results))
    tmp.replace(path)  # atomic: a killed run never leaves half a file
    atomic_write_bytes(path.with_suffix(".json"),
                       json.dumps(config, indent=1, default=str).encode())
    return demos


def run_cell(cell: Cell, profile: Profile, backend: str, sims: Simulators, source_result=None,
             progress=False, devices=None):
    """Run one experiment with ``jg.learn`` and return its LearnResult (not yet saved)."""
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
                                demos=cell_demos(cell, profile, backend, sims), **common)
        demos = cell_demos(cell, profile, backend, sims) if needs_demos(cell) else None
        return learn.transfer(source_result, sim.obj, modes=cell.column, demos=demos, **common)

    try:
        return run()
    except CheckpointMismatch:
        set_aside(cell)  # a killed run of another configuration: keep it, start afresh
        return run()


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
                    snapshot, log):
    """Run every cell without a matching saved result (``resume``: reuse those), saving each
    as it finishes; a failed cell is recorded in ``failures`` and skips its dependants."""
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
    demo_failed = {}
    bar = progress_bar(quiet, total=len(todo), unit="exp", desc="experiments")
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
            source = load_saved(c.source) if c.source is not None else None
            sims(c.obj)  # compile the object's trial first: its time is reported apart
            t0 = time.perf_counter()
            try:
                result = run_cell(c, profile, backend, sims, source_result=source,
                                  progress=not quiet, devices=devices)
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
            result.info["physics"] = physics_key()
            result.save(c.path)
            timings["experiments"][c.id] = time.perf_counter() - t0
            snapshot(False)
            bar.update(1)
            if not quiet:
                tot = result.counts.sum(axis=0).tolist()
                bar.write(f"  {c.id}: success/slipped/collision/miss = {tot} over "
                          f"{result.num_chains} chains ({timings['experiments'][c.id]:.1f} s)",
                          file=sys.stderr)


def run_throughput(profile, backend, sims, timings, throughput, log):
    """trials/s per backend on the experiments' compiled trials; compile time apart."""
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
