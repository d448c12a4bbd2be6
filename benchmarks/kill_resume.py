"""Interruptions lose nothing: ``kill -9`` the bench at random moments, ``--resume``, compare.

    .venv/bin/python benchmarks/kill_resume.py [--kills 5] [--seed 0]
                                               [--out bench_out/kill_resume.json]

1. Runs ``python -m jaxgrasp.bench --profile smoke`` once uninterrupted (the reference; by
   default on the pitcher only, MuJoCo C, learn checkpoints every 4 steps, no figures and no
   speed measurement: 5 experiments, each writing 4 checkpoints).
2. Runs the same command in a fresh directory and kills it with SIGKILL ``--kills`` times:
   the first kill lands during a checkpoint write (the script polls for the atomic writer's
   temp file ``.checkpoint.npz.*.tmp`` and kills the moment it appears), the second at a
   uniformly random moment after its process started (start-up included), the others at a
   uniformly random moment after their process's first checkpoint/result save (so that they
   land while it works); the range, ``[0, 1.5 x reference time / (kills + 1)]``, leaves
   work for the next process. After each kill the next process is started with
   ``--resume``; after the last kill it runs to completion (stderr of each: ``run*.log``).
3. Compares the finished tables (``results.json`` ``tables``, ``tables.csv``) and every
   experiment's chain arrays (``runs/**/result.npz``) with the reference, checks that every
   ``.npz``/``.json`` under the output reads, and lists leftover temp files.

Prints a summary and writes it as JSON (``--out``). Exit status 0 when everything matched.
"""

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: Where the bench runs from: the repository, or a frozen copy of its code (``main``), so
#: that edits made to the working tree meanwhile cannot change the numbers between runs.
CODE = REPO


def freeze_code(dest: Path) -> Path:
    """Copy ``jaxgrasp/`` and ``assets/`` to ``dest`` (run with cwd ``dest``)."""
    import shutil

    if dest.exists():
        shutil.rmtree(dest)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(REPO / "jaxgrasp", dest / "jaxgrasp", symlinks=True, ignore=ignore)
    shutil.copytree(REPO / "assets", dest / "assets", ignore=ignore)
    return dest


def bench_cmd(out: Path, args, resume=False) -> list:
    cmd = [sys.executable, "-m", "jaxgrasp.bench", "--profile", args.profile, "--out", str(out),
           "--objects", args.objects, "--backend", args.backend, "--seed", str(args.seed),
           "--checkpoint-every", str(args.checkpoint_every), "--no-figures", "--no-throughput",
           "--quiet"]
    return cmd + (["--resume"] if resume else [])


def _env():
    env = dict(os.environ)
    env.setdefault("JAXGRASP_CACHE_DIR", str(REPO / ".cache" / "jax"))
    if CODE != REPO:
        env["PYTHONPATH"] = os.pathsep.join([str(CODE), env.get("PYTHONPATH", "")]).rstrip(
            os.pathsep)
    return env


def _tmp_files(out: Path) -> list:
    """Temp files of the atomic writers under ``out``."""
    if not out.exists():
        return []
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.name.endswith(".tmp")
                  or p.name.endswith(".tmp.npz"))


def _checkpoint_tmp(out: Path):
    """A checkpoint temp file being written right now, or None (fast: walks only runs/)."""
    runs = out / "runs"
    if not runs.exists():
        return None
    for dirpath, _, files in os.walk(runs):
        for f in files:
            if f.startswith(".checkpoint.npz.") and f.endswith(".tmp"):
                return os.path.join(dirpath, f)
    return None


def _save_signature(out: Path) -> set:
    """(path, mtime) of every checkpoint and result file under ``out``: changes on each save."""
    runs = out / "runs"
    if not runs.exists():
        return set()
    sig = set()
    for dirpath, _, files in os.walk(runs):
        for f in files:
            if f in ("checkpoint.npz", "result.json"):
                path = os.path.join(dirpath, f)
                try:
                    sig.add((path, os.stat(path).st_mtime_ns))
                except FileNotFoundError:
                    pass
    return sig


def run_and_kill(cmd, out: Path, log_path: Path, *, at=None, on_checkpoint_write=False,
                 after_first_save=False, timeout=3600):
    """Start ``cmd``; SIGKILL it when a checkpoint temp file appears (``on_checkpoint_write``),
    or ``at`` seconds after it started, or ``at`` seconds after its first checkpoint/result
    save (``after_first_save``: the kill lands while it works, not in its start-up).

    Returns a record: how and when it ended (``killed`` False if it finished first).
    """
    t0 = time.perf_counter()
    with open(log_path, "w") as err:
        proc = subprocess.Popen(cmd, cwd=CODE, env=_env(), stdout=subprocess.DEVNULL,
                                stderr=err)
        rec = {"resume": "--resume" in cmd, "killed": False}
        if on_checkpoint_write:
            rec["target"] = "checkpoint write"
            while proc.poll() is None:
                tmp = _checkpoint_tmp(out)
                if tmp is not None:
                    proc.send_signal(signal.SIGKILL)
                    rec["killed"] = True
                    rec["tmp_file"] = str(Path(tmp).relative_to(out))
                    break
                time.sleep(0.0005)
        else:
            wait = at
            if after_first_save:
                rec["target"] = f"random moment {at:.1f} s after its first save"
                base = _save_signature(out)
                while proc.poll() is None and _save_signature(out) <= base:
                    time.sleep(0.05)
                rec["first_save_s"] = round(time.perf_counter() - t0, 2)
            else:
                rec["target"] = f"random moment {at:.1f} s after start"
            try:
                proc.wait(timeout=max(wait, 0.001))
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGKILL)
                rec["killed"] = True
        proc.wait(timeout=timeout)
    rec["seconds"] = round(time.perf_counter() - t0, 2)
    rec["returncode"] = proc.returncode
    if rec["killed"]:
        rec["tmp_left_at_kill"] = _tmp_files(out)
    if proc.returncode not in (0, -signal.SIGKILL):
        rec["stderr_tail"] = log_path.read_text()[-2000:]
    return rec


def progress_of(out: Path) -> dict:
    """What a killed run had saved: finished experiments and the latest checkpoint steps."""
    done = sorted(str(p.parent.relative_to(out / "runs")) for p in
                  (out / "runs").rglob("result.json") if p.parent.name != "checkpoint") \
        if (out / "runs").exists() else []
    ckpts = {}
    if (out / "runs").exists():
        for p in (out / "runs").rglob("checkpoint.npz"):
            try:
                with np.load(p, allow_pickle=False) as z:
                    ckpts[str(p.parent.parent.relative_to(out / "runs"))] = json.loads(
                        str(z["meta_json"]))["step"]
            except Exception as e:  # noqa: BLE001 - a corrupt checkpoint is a finding
                ckpts[str(p.relative_to(out))] = f"UNREADABLE: {type(e).__name__}: {e}"
    return {"finished_experiments": done, "checkpoint_steps": ckpts}


def check_files(out: Path) -> list:
    """Every .npz and .json under ``out`` reads; returns the problems."""
    bad = []
    for p in out.rglob("*.npz"):
        if p.name.endswith(".tmp.npz"):
            continue
        try:
            with np.load(p, allow_pickle=False) as z:
                for k in z.files:
                    z[k]
        except Exception as e:  # noqa: BLE001
            bad.append(f"{p.relative_to(out)}: {type(e).__name__}: {e}")
    for p in out.rglob("*.json"):
        try:
            json.loads(p.read_text())
        except Exception as e:  # noqa: BLE001
            bad.append(f"{p.relative_to(out)}: {type(e).__name__}: {e}")
    return bad


#: Per-cell wall times: the only table entries that may differ between two runs.
TIMING_KEYS = ("wall_s",)


def _strip_timing(x):
    if isinstance(x, dict):
        return {k: _strip_timing(v) for k, v in x.items() if k not in TIMING_KEYS}
    if isinstance(x, list):
        return [_strip_timing(v) for v in x]
    return x


def _csv_without_timing(path: Path) -> list:
    import csv

    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in TIMING_KEYS}
                for row in csv.DictReader(f)]


def compare(ref: Path, out: Path) -> dict:
    """Tables (less the wall times) and chain arrays of two finished bench directories."""
    r_res = json.loads((ref / "results.json").read_text())
    o_res = json.loads((out / "results.json").read_text())
    rep = {
        "complete": bool(o_res.get("complete")),
        "ignored_table_keys": list(TIMING_KEYS),
        "tables_equal": _strip_timing(r_res["tables"]) == _strip_timing(o_res["tables"]),
        "tables_csv_equal": _csv_without_timing(ref / "tables.csv")
        == _csv_without_timing(out / "tables.csv"),
        "failures_equal": r_res.get("failures") == o_res.get("failures"),
        "experiments": 0,
        "arrays_differ": [],
    }
    for p in sorted((ref / "runs").rglob("result.npz")):
        if ".stale" in p.parts:
            continue
        rel = p.relative_to(ref)
        q = out / rel
        rep["experiments"] += p.parent.name != "checkpoint"
        if not q.is_file():
            rep["arrays_differ"].append(f"{rel}: missing")
            continue
        with np.load(p, allow_pickle=False) as a, np.load(q, allow_pickle=False) as b:
            for k in a.files:
                if k not in b.files or not np.array_equal(a[k], b[k], equal_nan=True):
                    rep["arrays_differ"].append(f"{rel}:{k}")
    rep["match"] = (rep["complete"] and rep["tables_equal"] and rep["tables_csv_equal"]
                    and rep["failures_equal"] and not rep["arrays_differ"])
    return rep


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=5, help="SIGKILLs before the final resume")
    ap.add_argument("--profile", default="smoke")
    ap.add_argument("--objects", default="pitcher")
    ap.add_argument("--backend", default="mujoco")
    ap.add_argument("--checkpoint-every", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0, help="bench seed (both runs)")
    ap.add_argument("--kill-seed", type=int, default=0, help="seed of the random kill moments")
    ap.add_argument("--min-kill-s", type=float, default=0.0, help="earliest random kill")
    ap.add_argument("--max-kill-frac", type=float, default=1.5,
                    help="latest random kill: this x reference wall time / (kills + 1) seconds")
    ap.add_argument("--reuse-reference", action="store_true",
                    help="keep the finished reference run (and frozen code) of an earlier call")
    ap.add_argument("--no-freeze", action="store_true",
                    help="run the working tree's code instead of a frozen copy")
    ap.add_argument("--workdir", type=Path, default=REPO / "bench_out" / "kill_resume")
    ap.add_argument("--out", type=Path, default=REPO / "bench_out" / "kill_resume.json")
    args = ap.parse_args(argv)
    if args.kills < 1:
        ap.error("--kills must be >= 1")
    rng = random.Random(args.kill_seed)
    import shutil

    global CODE
    log = lambda *a: print(*a, flush=True)  # noqa: E731
    ref, out = args.workdir / "reference", args.workdir / "interrupted"
    args.workdir.mkdir(parents=True, exist_ok=True)
    for d in (out,) if args.reuse_reference else (ref, out):
        if d.exists():
            shutil.rmtree(d)
    if not args.no_freeze:
        code = args.workdir / "code"
        CODE = code if (args.reuse_reference and code.exists()) else freeze_code(code)
        log(f"code frozen in {CODE} (both runs use it)")

    log(f"reference: {' '.join(bench_cmd(ref, args)[1:])}")
    if (ref / "results.json").is_file() and (ref / "reference_seconds").is_file():
        ref_s = float((ref / "reference_seconds").read_text())
        log(f"  reused (it took {ref_s:.1f} s)")
    else:
        t0 = time.perf_counter()
        r = subprocess.run(bench_cmd(ref, args), cwd=CODE, env=_env(), capture_output=True,
                           text=True)
        ref_s = time.perf_counter() - t0
        if r.returncode != 0:
            log(r.stderr[-3000:])
            raise SystemExit(f"reference run failed ({r.returncode})")
        (ref / "reference_seconds").write_text(f"{ref_s:.2f}")
        log(f"  finished in {ref_s:.1f} s")

    # Random moments short enough that every killed process leaves work for the next.
    lo = args.min_kill_s
    hi = max(lo + 5.0, args.max_kill_frac * ref_s / (args.kills + 1))
    runs, kills = [], 0
    resume = False
    while kills < args.kills:
        on_write = kills == 0  # the first kill targets a checkpoint write
        at = None if on_write else rng.uniform(lo, hi)
        # The second kill: from the process start (may land in its start-up); the others
        # after the process's first save (while it works).
        rec = run_and_kill(bench_cmd(out, args, resume), out,
                           args.workdir / f"run{len(runs) + 1}.log", at=at,
                           on_checkpoint_write=on_write, after_first_save=kills >= 2)
        rec.update(progress_of(out))
        runs.append(rec)
        kills += rec["killed"]
        log(f"run {len(runs)} ({'resume' if resume else 'fresh'}, {rec['target']}): "
            f"{'KILLED' if rec['killed'] else 'finished'} after {rec['seconds']} s, rc "
            f"{rec['returncode']}; saved: {len(rec['finished_experiments'])} experiments, "
            f"checkpoints {rec['checkpoint_steps']}"
            + (f"; temp files at kill: {rec['tmp_left_at_kill']}" if rec["killed"] else ""))
        if rec["returncode"] not in (0, -signal.SIGKILL):
            log(rec.get("stderr_tail", ""))
        resume = True
        if not rec["killed"]:
            if on_write:
                # Finished before any checkpoint write was caught: start over, fresh.
                log("  no checkpoint write caught; starting the interrupted series again")
                shutil.rmtree(out)
                resume = False
            else:
                break  # finished before the random moment; the kills so far stand
    final = run_and_kill(bench_cmd(out, args, True), out, args.workdir / "final.log",
                         at=3600)
    final.update(progress_of(out))
    runs.append(final)
    log(f"final resume: rc {final['returncode']} after {final['seconds']} s")
    if final["returncode"] != 0:
        log(final.get("stderr_tail", ""))

    cmp = compare(ref, out) if (out / "results.json").is_file() else {"match": False}
    bad = check_files(out)
    leftover = _tmp_files(out)
    report = dict(
        command=" ".join(bench_cmd(Path("DIR"), args)[1:]),
        reference_seconds=round(ref_s, 1),
        kills=kills,
        runs=runs,
        comparison=cmp,
        unreadable_files=bad,
        leftover_tmp_files=leftover,
        set_aside=sorted(str(p.relative_to(out)) for p in out.rglob(".stale/*/*/*/*")),
        passed=bool(cmp.get("match")) and not bad and not leftover and kills >= args.kills,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    on_write = sum(r.get("target") == "checkpoint write" and r["killed"] for r in runs)
    log(f"\n{kills} SIGKILLs ({on_write} during a checkpoint write), {len(runs)} processes "
        "in all")
    log(f"tables equal: {cmp.get('tables_equal')}, tables.csv equal: "
        f"{cmp.get('tables_csv_equal')}, chain arrays differing: {cmp.get('arrays_differ')}, "
        f"experiments compared: {cmp.get('experiments')}")
    log(f"unreadable files: {bad or 'none'}; leftover temp files: {leftover or 'none'}")
    log(f"{'PASS' if report['passed'] else 'FAIL'}; wrote {args.out}")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
