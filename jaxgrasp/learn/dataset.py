"""``python -m jaxgrasp.learn DIR_OR_GLOB --out DATASET``: a grasp dataset for many meshes.

Every mesh of a folder (searched recursively) or a glob is learned by the single-object
command (the same files, in ``DATASET/<object>/``), one object per Dask task, on a
``LocalCluster`` of worker processes sized for this machine or on a running cluster
(``--scheduler``). ``DATASET/index.csv``, ``index.json`` and ``index.html`` list every object
with its status, counts and error. Each object's seed derives from the base ``--seed`` and the
sha256 of its mesh file, so its grasps do not depend on the order, the worker count or on
resuming; the same command again skips the finished objects, resumes a half-done one from its
checkpoint and tries a failed one again. Every object gets the same learning flags (``--method``,
``--learn-tries``, ``--slip-scale``, ``--robust-estimate``, ``--param``); ``DATASET/dataset.json``
records them (the method and the non-default LearnParams fields) and each object's
``command.json`` its own, so a rerun with other values is refused, not mixed in.
"""

import contextlib
import csv
import fcntl
import glob
import hashlib
import html
import io
import json
import os
import subprocess
import sys
import time
import traceback
from pathlib import Path

from jaxgrasp import _dask
from jaxgrasp._cli import USER_ERRORS, fail, interrupted, stopped
from jaxgrasp.learn import _flags
from jaxgrasp.learn.files.atomic import atomic_write_bytes
from jaxgrasp.objects import MESH_SUFFIXES

__all__ = ["COLUMNS", "add_arguments", "find_meshes", "is_dataset", "learn_object", "main",
           "object_seed"]

#: The index's columns, in order (``index.csv``; each row of ``index.json``).
COLUMNS = ("object", "mesh", "mesh_sha256", "seed", "status", "demos", "trials", "successes",
           "distinct_new", "robust_share", "distinct_robust_new", "seconds", "error")
ROW_FILE = "dataset_row.json"  # in each object's directory: its index row, written by its task
SETTINGS_FILE = "dataset.json"
#: What a ``dataset.json`` written before a setting was recorded held for it.
_UNRECORDED = {"method": "kameleon_darting", "learn_params": {}, "grow": 0,
               "grow_antipodal": 0, "grow_every": 0, "sketch": "biased"}
# The single-object flags a dataset passes on to every object (``args`` attribute, flag).
_PASSED_ON = (("chains", "--chains"), ("iterations", "--iterations"), ("burn_in", "--burn-in"),
              ("gripper", "--gripper"), ("scale", "--scale"),
              ("robust_tries", "--robust-tries"), ("pose_error", "--pose-error"),
              ("grow", "--grow"), ("grow_antipodal", "--grow-antipodal"),
              ("grow_every", "--grow-every"), ("sketch", "--sketch"))


def add_arguments(p) -> None:
    """The dataset flags of ``python -m jaxgrasp.learn`` (a folder or glob only)."""
    g = p.add_argument_group("a folder or glob of meshes (a dataset)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="Dask worker processes of the local cluster, one object each at a "
                        "time (default: half the CPU cores; 1: in this process, no cluster)")
    g.add_argument("--threads-per-worker", type=int, default=1, metavar="N",
                   help="Dask threads per worker (default 1: XLA has its own thread pool; "
                        "a process still learns one object at a time)")
    _dask.add_scheduler_argument(g, "the meshes and --out")


def is_dataset(spec: str) -> bool:
    """Whether the command's object is a folder or a glob (not one mesh or shipped name)."""
    path = Path(spec)
    return path.is_dir() or (not path.exists() and glob.has_magic(spec))


def find_meshes(spec: str) -> list:
    """``[(object name, mesh path)]`` of a folder (recursive) or glob, sorted by name.

    A name is the mesh's path below the folder (or below the glob's first wildcard part),
    suffix dropped, ``/`` written ``__``: it depends on the file alone, not on the others.

    Raises
    ------
    ValueError
        No mesh matches, or two meshes would get one name.
    """
    if Path(spec).is_dir():
        base = Path(spec)
        paths = [p for p in base.rglob("*") if not any(part.startswith(".") for part in
                                                       p.relative_to(base).parts)]
    else:
        parts = Path(spec).parts
        fixed = next((i for i, part in enumerate(parts) if glob.has_magic(part)), len(parts))
        base = Path(*parts[:fixed]) if fixed else Path()
        paths = [Path(p) for p in glob.glob(spec, recursive=True)]
    found = {}
    for path in sorted(p for p in paths if p.suffix.lower() in MESH_SUFFIXES and p.is_file()):
        name = "__".join(path.relative_to(base).with_suffix("").parts)
        if name in found:
            raise ValueError(f"{found[name]} and {path} would both be object {name!r}: "
                             "rename one")
        found[name] = path
    if not found:
        raise ValueError(f"{spec}: no mesh files ({', '.join(MESH_SUFFIXES)}) there")
    return sorted(found.items())


def mesh_sha256(path) -> str:
    """The sha256 of a mesh file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def object_seed(base_seed: int, sha256: str) -> int:
    """An object's seed in ``[0, 2**31)``: from the base seed and its mesh file's sha256 only,
    so it is the same in any order, on any worker and after a resume."""
    digest = hashlib.sha256(f"{int(base_seed)}/{sha256}".encode()).digest()
    return int.from_bytes(digest[:4], "big") >> 1


def _summary_values(text: str) -> dict:
    """``{label: value}`` of the single-object command's ``summary.md`` table."""
    rows = (line.strip().strip("|").split("|") for line in text.splitlines()
            if line.startswith("| ") and line.count("|") == 3)
    return {k.strip(): v.strip() for k, v in rows}


def _row_of(out: Path, job: dict) -> dict:
    """The index row of a learned object, read from what the single command wrote."""
    values = _summary_values((out / "summary.md").read_text())
    meta = json.loads((out / "run" / "result.json").read_text())
    robust = next((v for k, v in values.items() if k.startswith("robust grasps")), None)
    exported = int(values["exported grasps"])
    spent = json.loads((out / "timings.json").read_text())["seconds"]
    return {**_row_start(job), "status": "ok", "demos": int(meta["num_demos"]),
            "trials": sum(int(v) for v in meta["totals"].values()),
            "successes": int(meta["totals"]["success"]),
            "distinct_new": int(values["distinct new grasps (not a demo)"]),
            "robust_share": (None if robust is None or not exported
                             else round(int(robust.split()[0]) / exported, 4)),
            "distinct_robust_new": (None if robust is None
                                    else int(values["distinct robust new grasps"])),
            "seconds": round(float(sum(spent)), 1), "error": ""}


def _row_start(job: dict) -> dict:
    return dict.fromkeys(COLUMNS) | {k: job[k] for k in ("object", "mesh", "mesh_sha256",
                                                         "seed")}


def _failed(job: dict, error: str, seconds=None) -> dict:
    return {**_row_start(job), "status": "failed", "seconds": seconds, "error": error}


def learn_object(single, job: dict) -> dict:
    """Learn one object with the single-object command ``single`` (a Dask task): its index
    row, also written to ``<its directory>/dataset_row.json``.

    Its output (the summary, or a traceback) goes to ``learn.log`` there. A user error or any
    other exception makes a failed row with the error; Ctrl-C is raised. A lock on the object's
    directory makes a second task for it (a worker left over from a killed client) wait.
    """
    out = Path(job["out"])
    out.mkdir(parents=True, exist_ok=True)
    log = io.StringIO()
    t0 = time.perf_counter()
    with _dask.ONE_AT_A_TIME, open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
                code = single(job["argv"])
        except Exception as err:  # noqa: BLE001 - one object's bug must not stop the dataset
            if interrupted(err):
                raise KeyboardInterrupt from err
            log.write(traceback.format_exc())
            code, error = None, f"{type(err).__name__}: {err}"
        atomic_write_bytes(out / "learn.log", log.getvalue().encode())
        if code == 130:
            raise KeyboardInterrupt(f"{job['object']} interrupted")
        if code == 0:
            row = _row_of(out, job)
        else:
            if code is not None:  # the single command printed "error: ..." and returned 2
                error = next((ln[len("error: "):] for ln in log.getvalue().splitlines()
                              if ln.startswith("error: ")), f"exit code {code}")
            row = _failed(job, error, round(time.perf_counter() - t0, 1))
        atomic_write_bytes(out / ROW_FILE, json.dumps(row, indent=1).encode())
    return row


def _check_settings(out: Path, settings: dict) -> None:
    """A dataset directory belongs to one set of flags: refuse to mix another."""
    record = out / SETTINGS_FILE
    if record.exists():
        have = {**_UNRECORDED, **json.loads(record.read_text())}
        diff = {k: (have.get(k), v) for k, v in settings.items() if have.get(k) != v}
        if diff:
            raise ValueError(f"{out} holds a dataset with other settings {diff}; use another "
                             "--out")
    atomic_write_bytes(record, json.dumps(settings, indent=1).encode())


def _passed(args) -> dict:
    """The single-object settings a dataset passes on (None: not passed, each object
    chooses: its recipe where no flag of one was given, and ``--grow`` from that)."""
    chosen = _flags.recipe_given(args)
    return {a: getattr(args, a) if chosen or a not in _flags.RECIPE_FLAGS else None
            for a, _ in _PASSED_ON}


def _jobs(args, out: Path) -> list:
    """One job per mesh of ``args.object``: name, paths, hash, seed and the command line."""
    passed = _passed(args)
    flags = [*(str(x) for attr, flag in _PASSED_ON if passed[attr] is not None
               for x in (flag, passed[attr])), *_flags.passed_on(args)]
    jobs = []
    for name, mesh in find_meshes(args.object):
        job = {"object": name, "mesh": str(mesh), "mesh_sha256": None, "seed": None,
               "out": str((out / name).resolve())}
        try:
            job["mesh_sha256"] = mesh_sha256(mesh)
        except OSError as err:
            job["error"] = f"{mesh}: cannot read it ({err.strerror or err})"
            jobs.append(job)
            continue
        job["seed"] = object_seed(args.seed, job["mesh_sha256"])
        job["argv"] = [str(mesh.resolve()), "--out", job["out"], *flags,
                       "--seed", str(job["seed"]), "--quiet"]
        jobs.append(job)
    return jobs


def _done(job: dict) -> dict | None:
    """The saved row of a job finished before with this mesh and seed, else None."""
    path = Path(job["out"]) / ROW_FILE
    if "error" in job or not path.exists():
        return None
    row = json.loads(path.read_text())
    same = all(row.get(k) == job[k] for k in ("object", "mesh_sha256", "seed"))
    return {**row, "mesh": job["mesh"]} if same and row.get("status") == "ok" else None


def write_index(out: Path, rows: list) -> None:
    """``index.csv``, ``index.json`` and ``index.html`` of ``rows`` (in object order)."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: "" if row.get(k) is None else row[k] for k in COLUMNS} for row in rows)
    atomic_write_bytes(out / "index.csv", text.getvalue().encode())
    atomic_write_bytes(out / "index.json", json.dumps(
        {"totals": totals(rows), "objects": [{k: row.get(k) for k in COLUMNS} for row in rows]},
        indent=1).encode())
    atomic_write_bytes(out / "index.html", index_html(rows).encode())


def totals(rows: list) -> dict:
    """The dataset's counts: objects by status and the sums of the learned objects."""
    ok = [r for r in rows if r.get("status") == "ok"]
    out = {"objects": len(rows), "ok": len(ok),
           "failed": sum(r.get("status") == "failed" for r in rows),
           "pending": sum(r.get("status") not in ("ok", "failed") for r in rows)}
    for key in ("trials", "successes", "distinct_new", "distinct_robust_new"):
        out[key] = sum(r[key] or 0 for r in ok)
    return out


def index_html(rows: list) -> str:
    """An offline page: one table row per object, its name linking to its ``grasps.html``."""
    esc = html.escape

    def cell(row, key):
        value = row.get(key)
        if key == "object" and row.get("status") == "ok":
            return f'<a href="{esc(row["object"])}/grasps.html">{esc(row["object"])}</a>'
        if key == "robust_share" and value is not None:
            return f"{100 * value:.1f} %"
        return "" if value is None else esc(str(value))

    keys = [k for k in COLUMNS if k not in ("mesh_sha256",)]
    head = "".join(f"<th>{k.replace('_', ' ')}</th>" for k in keys)
    body = "".join(f'<tr class="{esc(str(r.get("status")))}">'
                   + "".join(f"<td>{cell(r, k)}</td>" for k in keys) + "</tr>\n" for r in rows)
    t = totals(rows)
    failed = f", {t['failed']} failed" if t["failed"] else ""
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>jaxgrasp dataset"
            "</title><style>body{font-family:sans-serif}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:2px 6px}tr.failed{background:#fdd}"
            "</style></head><body>\n"
            f"<h1>Grasp dataset: {t['ok']} of {t['objects']} objects learned{failed}</h1>\n"
            f"<p>{t['trials']} trials, {t['successes']} successes, {t['distinct_new']} distinct "
            "new grasps. Each object's page opens offline.</p>\n"
            f"<table><tr>{head}</tr>\n{body}</table></body></html>\n")


#: What the background decomposition process runs: each mesh (JSON on stdin: [mesh, scale,
#: the object's lock file]) decomposed into the cache as ``from_mesh`` would, at the lowest CPU
#: priority, skipping those a worker has started (their lock exists); it stops when its parent
#: is gone. A mesh that fails here fails again, with its message, in the worker.
_AHEAD = """
import json, os, sys
from pathlib import Path
from jaxgrasp.objects.user import from_mesh
os.nice(19)
parent = os.getppid()
for mesh, scale, lock in json.load(sys.stdin):
    if os.getppid() != parent:
        break
    if not Path(lock).exists():
        try:
            from_mesh(mesh, scale=scale)
        except Exception:
            pass
"""


def decompose_ahead(jobs: list, scale: float) -> subprocess.Popen | None:
    """Start a process that decomposes the meshes of ``jobs`` (in order) into the decomposition
    cache at the lowest CPU priority, so a worker reaching one loads it in milliseconds instead
    of running CoACD (seconds) while the cores wait. It runs on the learning's idle CPU; None
    when there is nothing to decompose."""
    todo = [[j["mesh"], float(scale), str(Path(j["out"]) / ".lock")] for j in jobs
            if "error" not in j]
    if not todo:
        return None
    proc = subprocess.Popen([sys.executable, "-c", _AHEAD], stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc.stdin.write(json.dumps(todo).encode())
    proc.stdin.close()
    return proc


def _default_workers() -> int:
    # about two cores per object: the sampler's XLA thread and the trials' MuJoCo calls
    return max(1, (os.cpu_count() or 1) // 2)


def _run_dask(todo: list, single, args, finished) -> None:
    """Run ``todo`` on a Dask cluster, calling ``finished(job, row)`` as each ends."""
    # Dask only for a dataset: one object needs no cluster (and loads none of it)
    from dask.distributed import as_completed

    with _dask.client(args.scheduler, args.workers, args.threads_per_worker) as client:
        futures = {client.submit(learn_object, single, job, pure=False): job for job in todo}
        for future in as_completed(futures):
            job = futures[future]
            try:
                row = future.result()
            except KeyboardInterrupt:
                raise
            except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: the worker died
                row = _failed(job, f"{type(err).__name__}: {err}")  # tried again on a rerun
            finished(job, row)


def main(args, single) -> int:
    """Learn a dataset for the parsed command line ``args`` of ``python -m jaxgrasp.learn``;
    ``single`` is the single-object command (``main(argv) -> exit code``) each object runs.

    Returns 0 when every object was learned, 1 when some failed (the index says why), 2 for a
    bad command line, 130 after Ctrl-C.
    """
    args.grow = _flags.grow_budget(args)
    # The progress bar, only for a dataset
    from tqdm.auto import tqdm

    out = Path(args.out)
    t0 = time.perf_counter()
    try:
        if args.demos:
            raise ValueError("--demos is one object's demonstrations: not for a folder or glob")
        for flag, value in (("--workers", args.workers),
                            ("--threads-per-worker", args.threads_per_worker)):
            if value is not None and value < 1:
                raise ValueError(f"{flag} must be >= 1, got {value}")
        _, learn_record = _flags.learn_params(args)  # a bad value: refused before any object
        jobs = _jobs(args, out)
        out.mkdir(parents=True, exist_ok=True)
        _check_settings(out, {"seed": args.seed, **_passed(args),
                              "method": args.method, "learn_params": learn_record})
    except USER_ERRORS as err:
        return fail(err)
    rows = {j["object"]: _done(j) or {**_row_start(j), "status": "pending"} for j in jobs}
    for job in jobs:
        if "error" in job:
            rows[job["object"]] = _failed(job, job["error"])
    todo = [j for j in jobs if rows[j["object"]]["status"] == "pending"]
    skipped = len(jobs) - len(todo)
    if args.workers is None:
        args.workers = max(1, min(_default_workers(), len(todo)))
    write_index(out, list(rows.values()))
    bar = tqdm(total=len(jobs), initial=skipped, unit="object", disable=args.quiet,
               desc=f"objects ({args.scheduler or f'{args.workers} workers'})")

    def finished(job, row):
        rows[job["object"]] = row
        write_index(out, list(rows.values()))  # after each object: a killed run loses none
        bar.update(1)
        bar.set_postfix_str(f"{job['object']} {row['status']}")

    # a running cluster's workers may have their own caches, on other hosts: nothing ahead
    ahead = None if args.scheduler else decompose_ahead(todo[args.workers:], args.scale)
    try:
        with bar:
            if args.workers == 1 and not args.scheduler:
                for job in todo:  # in this process: no cluster to start
                    finished(job, learn_object(single, job))
            elif todo:
                _run_dask(todo, single, args, finished)
    except KeyboardInterrupt:
        write_index(out, list(rows.values()))
        return stopped(f"the finished objects and the half-done ones' checkpoints are kept in "
                       f"{out}; run the same command again to resume")
    finally:
        if ahead is not None:
            ahead.kill()  # what it has written stays: whole cache files only
            ahead.wait()
    rows = list(rows.values())
    t = totals(rows)
    print(f"{t['ok']} of {t['objects']} objects learned ({skipped} before), {t['failed']} "
          f"failed; {t['trials']} trials, {t['successes']} successes, {t['distinct_new']} "
          f"distinct new grasps, {t['distinct_robust_new']} distinct robust new; "
          f"{time.perf_counter() - t0:.0f} s")
    for row in rows:
        if row["status"] == "failed":
            print(f"  failed: {row['object']}: {row['error']}")
    print(f"wrote {out}/index.csv, index.json, index.html and one directory per object")
    return 0 if t["failed"] == 0 else 1
