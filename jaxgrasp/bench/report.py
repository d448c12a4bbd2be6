"""Outputs of a bench run, rebuilt from the saved results: ``results.json`` (validated against
:mod:`~jaxgrasp.bench.schema`), ``tables.md``, ``tables.csv``, the printed summary and the
figures (drawn by :mod:`~jaxgrasp.bench.figures`)."""

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from jaxgrasp import objects
from jaxgrasp.bench import env, figures, paper, tables
from jaxgrasp.bench.plan import learn_params, load_saved, matches
from jaxgrasp.bench.profiles import ACTIVE_METHODS, TRANSFER_MODES, Profile
from jaxgrasp.bench.schema import SCHEMA, SCHEMA_VERSION, validate
from jaxgrasp.bench.throughput import MAX_ENGINE_RATIO
from jaxgrasp.learn.files.atomic import atomic_write_bytes
from jaxgrasp.physics.gripper import GripperParams


def cell_from_result(result, **extra) -> dict:
    """A table cell (``tables.make_cell``) from a LearnResult; its robustness fields are null
    where the cell's grasps were not measured (and the share where it has none)."""
    jump = result.jump_rate
    rob, share = result.robustness, result.robust_share
    return tables.make_cell(
        result.counts,
        result.num_steps,
        acceptance_rate=float(np.mean(result.acceptance_rate)),
        jump_rate=float(np.mean(jump)) if result.method != "random_walk" else None,
        learned_grasps=int(len(result.learned.distinct)),
        new_grasps=int(len(result.learned.new)),
        repeat_share=float(result.learned.repeat_share),
        robust_share=share if share is not None and np.isfinite(share) else None,
        distinct_robust_new=result.distinct_robust_new,
        robustness_trials=None if rob is None else rob.num_trials,
        seed=int(result.seed),
        **extra,
    )


#: (result directory, its files' mtimes and sizes) -> (table cell, learned grasps): the run
#: writes a snapshot after every experiment, and a cell's learned-grasp counts cost seconds
#: (~9 s for 8 x 1100 proposals): each saved result is summarized once per process.
_CELLS: dict = {}


def _cached_cell(c, r, noise, **extra) -> dict:
    """The cell of saved result ``r``; its robustness only when measured under ``noise`` (the
    run's ``profile.noise``: another measurement is not this run's)."""
    files = (c.path / "result.npz", c.path / "result.json")
    key = (str(c.path.resolve()), tuple((f.stat().st_mtime_ns, f.stat().st_size)
                                        for f in files if f.exists()), noise)
    if key in _CELLS:
        r.__dict__["learned"] = _CELLS[key][1]  # the cached_property, for the figures
    else:
        other = r.robustness is not None and r.robustness.noise != noise
        _CELLS[key] = cell_from_result(r.with_robustness(None) if other else r), r.learned
    return {**_CELLS[key][0], **extra}


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
            active.setdefault(c.key[0], {})[c.key[1]] = _cached_cell(c, r, profile.noise,
                                                                     **extra)
        else:
            extra["source"] = c.source.id
            s, o, m = c.key
            transfer.setdefault(s, {}).setdefault(o, {})[m] = _cached_cell(c, r, profile.noise,
                                                                           **extra)
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
                  pose_error=[float(v) for v in profile.pose_error],
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


def write_outputs(out: Path, results: dict, profile: Profile) -> None:
    """results.json (validated), tables.md, tables.csv, results.schema.json — atomically."""
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
        tables.render_tables(tbl, profile, markdown=True),
        "",
        "## Learned grasps",
        "",
        "Successes over all chains, the distinct successful grasps, and how many of those are "
        "not one of the demonstrated grasps (chains start at the demos and GDMC jumps land on "
        "them, so re-proposed demos count as successes in the tables).",
        "",
        tables.render_learned(tbl, markdown=True),
        *(["", note] if (note := tables.robustness_note(tbl, profile)) else []),
        "",
        "## The paper's claims",
        "",
        "The same predicate runs on the paper's numbers and on this run's point estimates "
        "(success *rates*; `>2 SE` marks differences larger than twice the standard error "
        "across chains). A claim is REPRODUCED only when this run's point estimates agree "
        f"with the paper *and* its one-sided test passes at α = {paper.ALPHA:g}; otherwise "
        "it is *not shown*, with its p-value. Chains are the tests' independent units: "
        "`rank test p` is the one-sided Mann-Whitney U test on the chains' counts (exact "
        "permutation p), a claim over several pairs or cells takes the largest p (each must "
        "pass); \"finds grasps\" needs a success rate above "
        f"{100 * paper.MIN_SUCCESS_RATE:g} % in every cell (5x the paper's random walk), "
        "tested by an exact binomial test on the pooled proposals and a t-test over chains "
        "(the larger p). With 2 chains per cell a rank test cannot reach p < 1/6.",
        "",
        tables.render_claims_markdown(results["comparison"]["claims"]),
        "",
        "## Throughput",
        "",
        tables.render_throughput(results["throughput"], markdown=True),
        "",
        "Only the run's backend is measured. `÷ rollout alone`: full trials/s ÷ the MuJoCo "
        "rollout alone on the same placed states; the trial is that rollout plus placement, "
        "contacts and epsilon, so the ratio is below 1 (a few hundredths of timing noise "
        f"aside); above {MAX_ENGINE_RATIO:g} it is shown as a measurement error, not a "
        "result.",
        "",
        wall_time_caption(results["timings"]),
        "",
    ]
    if results["figures"]:
        md += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in results["figures"]]
    atomic_write_bytes(out / "tables.md", ("\n".join(md) + "\n").encode())


def wall_time_caption(timings: dict) -> str:
    """The run's wall time and what it is (:func:`jaxgrasp.bench.run.account_time`)."""
    t = timings
    exp = t.get("experiments_s", sum(t["experiments"].values()))
    setup = t.get("setup_s", max(t["total_s"] - exp, 0.0))
    thr = f" ({t['throughput_s']:.1f} s)" if "throughput_s" in t else ""
    rob = (f", the robustness of the cells' grasps ({t['robustness_s']:.1f} s)"
           if t.get("robustness_s") else "")
    return (f"Wall time {t['total_s']:.1f} s = experiments {exp:.1f} s (each experiment's own "
            f"time, counted once: a `--resume` adds only the experiments it runs, a "
            f"`--report-only` redraw adds nothing) + setup {setup:.1f} s (compiling each "
            f"object's trial once). Not included: starting Python and JAX, the throughput "
            f"measurement{thr}{rob}, figures and reports. With `--jobs` > 1 experiments overlap: "
            f"this is their work time, not the elapsed time.")


def print_summary(res: dict, profile: Profile, out: Path) -> None:
    """The run's tables, claims, throughput and failures on stdout."""
    print()
    print(tables.render_tables(res["tables"], profile, markdown=False))
    if res["tables"]["active"] or res["tables"]["transfer"]:
        print()
        print("Learned grasps (successes include re-proposed demonstrations):")
        print(tables.render_learned(res["tables"], markdown=False))
        note = tables.robustness_note(res["tables"], profile)
        if note:
            print(note)
    print()
    print(tables.render_claims_text(res["comparison"]["claims"]))
    if res["throughput"]:
        print()
        print("Throughput")
        print(tables.render_throughput(res["throughput"], markdown=False))
    if res.get("failures"):
        print()
        print("FAILED experiments (not in the tables):")
        for k, v in res["failures"].items():
            print(f"  {k}: {v}")
    print()
    print(f"Wrote {out}/results.json, tables.md, tables.csv"
          + (f" and {len(res['figures'])} figures in {out}/figures" if res["figures"] else "")
          + f" (wall time {res['timings']['total_s']:.1f} s: experiments + setup).")


# ---------------------------------------------------------------------------------------------
# Figures


def gripper_drawing() -> dict:
    """How a grasp is drawn, from the gripper's geometry (jaxgrasp.physics.gripper): approach
    along the grasp frame's +z (black line back to the palm), jaws closing along y (red line,
    the open span)."""
    g = GripperParams()
    return dict(approach_axis=(0.0, 0.0, 1.0), closing_axis=(0.0, 1.0, 0.0),
                span=g.max_opening, depth=g.pad_half_size[2] + 2 * g.palm_half_size[2])


def chain_epsilon(result) -> np.ndarray:
    """(steps, chains) epsilon of each chain's *state* (the last accepted proposal; NaN
    before the first acceptance: the start point's quality is not recorded)."""
    eps, acc = np.asarray(result.epsilons, float), np.asarray(result.accepted, bool)
    steps, chains = eps.shape
    idx = np.where(acc, np.arange(steps)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    return np.where(idx >= 0, eps[np.maximum(idx, 0), np.arange(chains)], np.nan)


def _title(cell, result):
    if cell.table == "active":
        col = tables.METHOD_TITLES[cell.column]
    else:
        col = f"{cell.key[0]}: {tables.MODES_TITLES[cell.column].lower()}"
    learned = result.learned
    # One fact per line: a 3-column grid leaves a panel ~40 characters of title.
    return (f"{cell.obj}\n{col}\n{len(learned.distinct)} distinct successes, "
            f"{len(learned.new)} new\n{len(result.modes)} modes")


def make_figures(out: Path, cells: list, results: dict, profile, load_mesh=None) -> list:
    """Write every figure of the run under ``out/figures``; return paths relative to ``out``.

    ``load_mesh(name) -> trimesh.Trimesh`` defaults to ``jg.objects.load(name).mesh``.
    """
    if load_mesh is None:

        def load_mesh(name):
            return objects.load(name).mesh

    fig_dir = out / "figures"
    (fig_dir / "grasps").mkdir(parents=True, exist_ok=True)
    draw = gripper_drawing()
    meshes = {}

    def mesh(name):
        if name not in meshes:
            meshes[name] = load_mesh(name)
        return meshes[name]

    written = []
    done = [c for c in cells if c.id in results]

    def panel(c):
        r = results[c.id]
        # GDMC modes are the demonstrated grasps the chain used (for transfer with source
        # modes: the similar object's); the random walk has none, show its demos.
        demos = r.modes if r.method != "random_walk" else r.demos.poses
        return dict(mesh=mesh(c.obj), grasps=r.grasps, demos=demos, title=_title(c, r))

    # Paper Fig. 5 layout: active set (biased sketch) on top, each transfer set below
    # (modes of the actual object).
    fig5 = [c for c in done if c.key[-1] in ("kameleon_darting_biased", "target")]
    if fig5:
        p = fig_dir / "fig5_grasps.png"
        figures.grasp_grid([panel(c) for c in fig5], p, ncols=3, **draw)
        written.append(p)
    for c in done:
        p = fig_dir / "grasps" / (c.id.replace("/", "_") + ".png")
        figures.grasp_grid([panel(c)], p, ncols=1, **draw)
        written.append(p)

    tbl_active = {}
    tbl_transfer = {}
    for c in done:
        cell = _cached_cell(c, results[c.id], profile.noise)
        if c.table == "active":
            tbl_active.setdefault(c.obj, {})[c.column] = cell
        else:
            tbl_transfer.setdefault(f"{c.key[0]}/{c.obj}", {})[c.column] = cell
    pub = paper.paper_tables()
    if tbl_active:
        p = fig_dir / "outcomes_active.png"
        figures.outcome_bars(tbl_active, pub["active"], p, columns=list(ACTIVE_METHODS),
                             titles=figures.ACTIVE_TITLES,
                             suptitle=f"Table II outcomes ({profile.proposals} proposals "
                                      f"x {profile.chains} chains; hatched: paper)")
        written.append(p)
    if tbl_transfer:
        pt = {f"{s}/{o}": row for s, b in pub["transfer"].items() for o, row in b.items()}
        p = fig_dir / "outcomes_transfer.png"
        figures.outcome_bars(tbl_transfer, pt, p, columns=list(TRANSFER_MODES),
                             titles=figures.TRANSFER_TITLES,
                             suptitle=f"Table III outcomes ({profile.proposals} proposals "
                                      f"x {profile.chains} chains; hatched: paper)")
        written.append(p)

    for table in ("active", "transfer"):
        sel = [c for c in done if c.table == table]
        if not sel:
            continue
        curves = {}
        for c in sel:
            panel_name = c.obj if table == "active" else f"{c.key[0]}/{c.obj}"
            curves.setdefault(panel_name, {})[c.column] = results[c.id].accepted
        p = fig_dir / f"acceptance_{table}.png"
        figures.acceptance_plot(curves, p, burn_in=profile.burn_in,
                                title=f"Running acceptance rate ({table}; mean over chains)")
        written.append(p)
        traces = {c.id.split("/", 1)[1]: chain_epsilon(results[c.id]) for c in sel}
        props = {c.id.split("/", 1)[1]: results[c.id].epsilons for c in sel}
        p = fig_dir / f"trace_{table}.png"
        # One row per table row: methods (Table II) or modes (Table III) side by side.
        ncols = len(ACTIVE_METHODS) if table == "active" else len(TRANSFER_MODES)
        figures.trace_plot(traces, p, burn_in=profile.burn_in, ylabel="epsilon", points=props,
                           ncols=ncols,
                           title=f"Chain traces ({table}): epsilon of each chain's state "
                                 "(lines, from its first accepted move) and of every proposal "
                                 "(dots)")
        written.append(p)
    return [str(Path(p).relative_to(out)) for p in written]
