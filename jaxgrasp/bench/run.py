"""Run the experiments of a profile, save every finished one, rebuild all outputs from disk.

Layout of an output directory::

    runs/active/<object>/<method>/result.{npz,json}         Table II cells (LearnResult.save)
    runs/transfer/<set>/<object>/<modes>/result.{npz,json}  Table III cells
    runs/<...>/checkpoint/                                  learn checkpoints (long profiles)
    results.json  tables.md  tables.csv  results.schema.json  figures/*.png

Tables are always recomputed from the saved results, so a killed bench loses at most the
experiment it was running, and ``--resume`` continues where it stopped.
"""

import json
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np

from jaxgrasp.bench import env, paper, tables
from jaxgrasp.bench.profiles import (
    ACTIVE_METHODS,
    ACTIVE_OBJECTS,
    TRANSFER_MODES,
    TRANSFER_SETS,
    TRANSFER_SOURCE_METHOD,
    Profile,
)
from jaxgrasp.bench.schema import SCHEMA, SCHEMA_VERSION, validate


def cell_seed(seed: int, row_id: str) -> int:
    """Reproducible seed per table row (a subset of objects gives the same numbers).

    All cells of a row share it, so the three methods on one object start from the same
    demonstrated grasps (as in the paper) and the two transfer modes from the same keys.
    """
    return int((seed * 1_000_003 + zlib.crc32(row_id.encode())) % (2**31 - 1))


def resolve_backend(backend: str) -> str:
    """The bench's ``auto``: :func:`jaxgrasp.physics.resolve_backend` (imported when needed,
    so that ``--help`` and ``--report-only`` never load MuJoCo)."""
    from jaxgrasp.physics.inputs import resolve_backend as resolve

    return resolve(backend)


class Cell:
    """One experiment: where it is saved and how to run it."""

    def __init__(self, table, key, obj, column, path, source=None):
        self.table = table  # "active" | "transfer"
        self.key = key  # ("pitcher", "random_walk") | ("transfer_a", "tall_pitcher", "source")
        self.obj = obj
        self.column = column
        self.path = Path(path)
        self.source = source  # transfer: the active Cell whose result is reused

    @property
    def id(self) -> str:
        return "/".join((self.table,) + self.key)

    @property
    def row_id(self) -> str:
        return "/".join((self.table,) + self.key[:-1])


def plan(profile: Profile, out: Path) -> list:
    """The cells of ``profile`` in run order (every transfer after its source)."""
    runs = out / "runs"
    cells, by_key = [], {}
    for o in profile.objects:
        for m in ACTIVE_METHODS:
            c = Cell("active", (o, m), o, m, runs / "active" / o / m)
            cells.append(c)
            by_key[(o, m)] = c
    for s in profile.transfer_sets:
        for a, t in zip(ACTIVE_OBJECTS, TRANSFER_SETS[s], strict=True):
            if a not in profile.objects:
                continue
            for mode in TRANSFER_MODES:
                cells.append(Cell("transfer", (s, t, mode), t, mode,
                                  runs / "transfer" / s / t / mode,
                                  source=by_key[(a, TRANSFER_SOURCE_METHOD)]))
    return cells


def learn_params(profile: Profile):
    from jaxgrasp.learn.params import LearnParams

    return LearnParams(iterations=profile.iterations, burn_in=profile.burn_in,
                       **dict(profile.params))


def physics_key() -> str:
    """The gripper and protocol the bench's trials run on (the library defaults). Saved
    results record it (``info["physics"]``), so a run directory from before a physics change
    is never resumed or tabled as this physics."""
    from jaxgrasp.physics import GripperParams, TrialParams

    return repr((GripperParams(), TrialParams()))


def matches(result, cell: Cell, profile: Profile, backend: str) -> bool:
    """A saved result belongs to this configuration (``--resume`` reuses only those)."""
    return (
        result.info.get("physics") == physics_key()
        and result.object_name == cell.obj
        and result.num_chains == profile.chains
        and result.num_steps == profile.proposals
        and result.seed == cell_seed(profile.seed, cell.row_id)
        and result.backend == backend
        and result.params == learn_params(profile)
    )


def set_aside(cell: Cell) -> Path | None:
    """Move a saved result of another configuration out of the way (``runs/.stale/...``)
    before its cell runs again; returns where it went."""
    import shutil
    from datetime import datetime

    if not cell.path.exists():
        return None
    runs = next(p for p in cell.path.parents if p.name == "runs")
    dest = runs / ".stale" / datetime.now().strftime("%Y%m%d-%H%M%S-%f") / cell.path.relative_to(
        runs)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(str(cell.path), str(dest))
    return dest


def load_saved(cell: Cell):
    """The LearnResult saved for ``cell``, or None."""
    from jaxgrasp.learn.results import load

    if not (cell.path / "result.json").is_file():
        return None
    return load(cell.path)


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
            from jaxgrasp import learn, objects
            from jaxgrasp.bench.throughput import warm_up

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
    import hashlib

    from jaxgrasp import learn
    from jaxgrasp.learn.results import (
        Demos,
        atomic_write_bytes,
        demo_result_arrays,
        demo_results_from_arrays,
    )

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
    from jaxgrasp import learn

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

    from jaxgrasp.learn.checkpoint import CheckpointMismatch

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


# ---------------------------------------------------------------------------------------------
# From saved results to tables


def cell_from_result(result, **extra) -> dict:
    """A table cell (``tables.make_cell``) from a LearnResult."""
    jump = result.jump_rate
    return tables.make_cell(
        result.counts,
        result.num_steps,
        acceptance_rate=float(np.mean(result.acceptance_rate)),
        jump_rate=float(np.mean(jump)) if result.method != "random_walk" else None,
        learned_grasps=int(len(result.learned.distinct)),
        new_grasps=int(len(result.learned.new)),
        repeat_share=float(result.learned.repeat_share),
        seed=int(result.seed),
        **extra,
    )


def collect(cells: list, out: Path, wall: dict, profile: Profile, backend: str) -> tuple:
    """(tables dict, {cell id: LearnResult}) from the results saved under ``out`` that belong
    to this configuration (a result of another seed/size/backend is never shown as this)."""
    active, transfer, results = {}, {}, {}
    for c in cells:
        r = load_saved(c)
        if r is None or not matches(r, c, profile, backend):
            continue
        results[c.id] = r
        extra = dict(saved=str(c.path.relative_to(out)))
        if c.id in wall:
            extra["wall_s"] = float(wall[c.id])
        if c.table == "active":
            active.setdefault(c.key[0], {})[c.key[1]] = cell_from_result(r, **extra)
        else:
            extra["source"] = c.source.id
            s, o, m = c.key
            transfer.setdefault(s, {}).setdefault(o, {})[m] = cell_from_result(r, **extra)
    return {"active": active, "transfer": transfer}, results


def build_results(profile: Profile, backend: str, tbl: dict, timings: dict, throughput: dict,
                  figures: list, complete: bool, failures: dict | None = None,
                  provenance: dict | None = None) -> dict:
    """The ``results.json`` document (validated against :data:`SCHEMA` before writing).

    ``provenance``: versions/device/git of the run that produced the results (a redraw with
    ``--report-only`` keeps them); default: this process.
    """
    prov = provenance or {}
    config = asdict(profile)
    config.update(profile=profile.name, objects=list(profile.objects),
                  transfer_sets=list(profile.transfer_sets), proposals=profile.proposals,
                  backend=backend, requested_backend=profile.backend,
                  params=learn_params(profile).to_dict())
    return {
        "schema_version": SCHEMA_VERSION,
        "complete": complete,
        "config": config,
        "versions": prov.get("versions") or env.versions(),
        "device": prov.get("device") or env.device(),
        "git": prov.get("git") or env.git_revision(),
        "timings": timings,
        "tables": tbl,
        "throughput": throughput,
        "comparison": {"claims": paper.evaluate_claims(tbl),
                       "paper_source": "paper.tex Tables II (tab:res_al), III (tab:res_tl)"},
        "figures": figures,
        "failures": dict(failures or {}),
    }


def render_tables(tbl: dict, profile: Profile, *, markdown: bool) -> str:
    """Both tables (this run, then the paper's) as text or Markdown."""
    render = tables.render_markdown if markdown else tables.render_text
    t2, t3 = tables.table_titles(profile.proposals, profile.chains)
    pub = paper.paper_tables()
    parts = []
    if tbl["active"]:
        parts.append(render(t2, *tables.active_grid(tbl["active"])))
    if tbl["transfer"]:
        parts.append(render(t3, *tables.transfer_grid(tbl["transfer"])))
    p2, p3 = tables.table_titles(paper.PAPER_PROPOSALS, 1)
    parts.append(render("Paper " + p2, *tables.active_grid(pub["active"])))
    parts.append(render("Paper " + p3, *tables.transfer_grid(pub["transfer"])))
    return "\n\n".join(parts)


def render_throughput(throughput: dict, *, markdown: bool) -> str:
    head = ("backend", "object", "batch", "compile s", "trials/s", "chain steps/s")
    rows = []
    for b, t in throughput.items():
        if not t.get("available"):
            rows.append((b, "-", "-", "-", f"unavailable: {t.get('error', '')}"[:60], "-"))
            continue

        def f(x, d=1):
            return "-" if x is None else f"{x:.{d}f}"

        rows.append((b, t.get("object", "-"), str(t.get("batch", "-")), f(t.get("compile_s")),
                     f(t.get("trials_per_s")), f(t.get("chain_steps_per_s"))))
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(lines)
    cols = zip(head, *rows, strict=True)
    w = [max(len(str(x)) for x in col) for col in cols]
    lines = ["  ".join(str(x).ljust(n) for x, n in zip(r, w, strict=True)) for r in [head, *rows]]
    return "\n".join(lines)


def write_outputs(out: Path, results: dict, profile: Profile) -> None:
    """results.json (validated), tables.md, tables.csv, results.schema.json — atomically."""
    from jaxgrasp.learn.results import atomic_write_bytes

    validate(results)
    tbl = results["tables"]
    atomic_write_bytes(out / "results.json",
                       json.dumps(results, indent=1, allow_nan=False).encode())
    atomic_write_bytes(out / "results.schema.json", json.dumps(SCHEMA, indent=1).encode())
    rows = tables.rows_for_csv(tbl, paper.paper_tables())
    atomic_write_bytes(out / "tables.csv", tables.to_csv(rows).encode())
    cfg = results["config"]
    dev = results["device"]
    md = [
        f"# jaxgrasp bench — profile `{cfg['profile']}`",
        "",
        f"{cfg['chains']} chains per cell, {cfg['burn_in']} burn-in + {cfg['iterations']} "
        f"iterations = {cfg['proposals']} proposals per run; backend `{cfg['backend']}`; "
        f"seed {cfg['seed']}; device {dev['platform']} ({', '.join(dev['devices'])}; "
        f"{dev['cpu']}, {dev['cpu_cores']} cores); git {results['git']['revision']}"
        + (" (dirty)" if results["git"].get("dirty") else "")
        + ("" if results["complete"] else "; **incomplete run**"),
        *([""] + [f"- FAILED `{k}`: {v}" for k, v in results["failures"].items()]
          if results.get("failures") else []),
        "",
        "Cells: mean ± sample sd across chains of the count per run. Paper: one run of "
        "1100 proposals per cell (RobWork); compare rates, not raw counts.",
        "",
        render_tables(tbl, profile, markdown=True),
        "",
        "## Learned grasps",
        "",
        "Successes over all chains, the distinct successful grasps, and how many of those are "
        "not one of the demonstrated grasps (chains start at the demos and GDMC jumps land on "
        "them, so re-proposed demos count as successes in the tables).",
        "",
        tables.render_learned(tbl, markdown=True),
        "",
        "## The paper's claims",
        "",
        "Verdicts are computed by the same predicate on the paper's numbers and on this run "
        "(success *rates*; `>2 SE` marks differences larger than twice the standard error "
        "across chains).",
        "",
        tables.render_claims_markdown(results["comparison"]["claims"]),
        "",
        "## Throughput",
        "",
        render_throughput(results["throughput"], markdown=True),
        "",
        f"Total wall time {results['timings']['total_s']:.1f} s.",
        "",
    ]
    if results["figures"]:
        md += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in results["figures"]]
    atomic_write_bytes(out / "tables.md", ("\n".join(md) + "\n").encode())
