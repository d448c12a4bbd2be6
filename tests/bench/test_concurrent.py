"""``python -m jaxgrasp.bench --jobs N``: concurrent experiments give the results of one at a
time, in dependency order, with demonstrations made once and failures recorded as before.

The scheduler tests replace the learning run by a fake (seconds, no physics); the real
comparison on a tiny profile is ``slow``.
"""

import threading
import time

import numpy as np
import pytest

from jaxgrasp.bench import plan, profiles, run
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos


def tiny_profile(**kw):
    """Every cell type on one object: 3 active cells, then a transfer pair on their source."""
    return profiles.get_profile("smoke").with_overrides(
        objects=("pitcher",), chains=2, iterations=4, burn_in=4, backend="mujoco", **kw)


def two_object_profile():
    return profiles.get_profile("smoke").with_overrides(
        objects=("pitcher", "plate"), transfer_sets=("transfer_a", "transfer_b"), chains=2,
        iterations=4, burn_in=4, backend="mujoco")


def fake_result(cell, profile):
    """A LearnResult whose arrays depend only on the cell's seed and column."""
    rng = np.random.default_rng([plan.cell_seed(profile.seed, cell.row_id),
                                 list(profiles.ACTIVE_METHODS).index(cell.column)
                                 if cell.table == "active" else 3 + (cell.column == "target")])
    steps, chains = profile.proposals, profile.chains
    outcomes = rng.choice(4, size=(steps, chains)).astype(np.int8)
    pos = rng.normal(0.0, 0.05, size=(steps, chains, 7)).astype(np.float32)
    pos[..., 3] += 1.0
    return LearnResult(
        object_name=cell.obj, object_hash="0" * 16, workflow=cell.table,
        method="kameleon_darting", sketch="biased", modes_kind="demos",
        seed=plan.cell_seed(profile.seed, cell.row_id), backend="mujoco",
        params=plan.learn_params(profile), positions=pos, proposals=pos + 0.01,
        outcomes=outcomes, epsilons=rng.random((steps, chains)).astype(np.float32),
        accepted=rng.random((steps, chains)) < 0.3, is_jump=rng.random((steps, chains)) < 0.4,
        initial_positions=pos[0], modes=pos[0, :3].astype(float),
        sketch_points=pos[:, 0].astype(float), demos=Demos(pos[0, :3].astype(float), None),
        info={})


#: A backstop only: a scheduler that runs cells at once starts the second within milliseconds.
OVERLAP_WAIT_S = 600.0


class FakeLearn:
    """Stands in for ``run.run_cell``: logs what ran when, checks what a cell may rely on."""

    def __init__(self, profile, fail_demos=(), delay=0.05, expect_overlap=False):
        self.profile, self.fail_demos, self.delay = profile, set(fail_demos), delay
        self.lock, self.log, self.active, self.max_active = threading.Lock(), [], 0, 0
        self.demos_made = {}
        # With expect_overlap, the first cells wait for a second one to start (not for a
        # time), so whether two cells ran at once does not depend on how busy the machine is.
        self.overlap, self.expect_overlap = threading.Event(), expect_overlap

    def __call__(self, cell, profile, backend, sims, source_result=None, progress=False,
                 devices=None, on_demos=None):
        with self.lock:
            self.active += 1
            self.max_active = max(self.max_active, self.active)
            self.log.append(("start", cell.id))
            if self.active > 1:
                self.overlap.set()
        try:
            if self.expect_overlap:
                self.overlap.wait(OVERLAP_WAIT_S)
            if cell.source is not None:
                # The source was saved before its transfer started.
                assert source_result is not None and plan.load_saved(cell.source) is not None
            time.sleep(self.delay * (1 + len(cell.id) % 3))  # unequal lengths
            if run.needs_demos(cell):
                with self.lock:
                    if cell.row_id not in self.demos_made:
                        self.demos_made[cell.row_id] = cell.id
                    if cell.row_id in self.fail_demos:
                        raise ValueError("no demonstrated grasp succeeded (test)")
                if on_demos is not None:
                    on_demos()
            time.sleep(self.delay)
            return fake_result(cell, self.profile)
        finally:
            with self.lock:
                self.active -= 1
                self.log.append(("end", cell.id))


class NoSims:
    def __call__(self, name, backend=None):
        return None


def run_bench(profile, out, jobs, fake, monkeypatch, workers="thread", **kw):
    monkeypatch.setattr(run, "run_cell", fake)
    cells = plan.plan(profile, out)
    timings, failures, snapshots = {"experiments": {}}, {}, []
    run.run_experiments(cells, profile, "mujoco", kw.pop("sims", NoSims()), timings, failures,
                        resume=False, quiet=True, devices=None, snapshot=snapshots.append,
                        log=lambda *a: None, jobs=jobs, workers=workers, **kw)
    return cells, timings, failures, snapshots


def saved_arrays(cells):
    return {c.id: plan.load_saved(c).arrays() for c in cells if plan.load_saved(c) is not None}


def assert_same_arrays(a, b):
    assert a.keys() == b.keys()
    for cid in a:
        assert a[cid].keys() == b[cid].keys(), cid
        for k in a[cid]:
            np.testing.assert_array_equal(a[cid][k], b[cid][k], err_msg=f"{cid}: {k}")


def test_jobs_respect_dependencies_and_save_the_sequential_results(tmp_path, monkeypatch):
    profile = two_object_profile()
    seq = FakeLearn(profile)
    cells, _, fail1, _ = run_bench(profile, tmp_path / "seq", 1, seq, monkeypatch)
    conc = FakeLearn(profile, expect_overlap=True)
    cells3, timings, fail3, snaps = run_bench(profile, tmp_path / "conc", 3, conc, monkeypatch)
    assert not fail1 and not fail3
    assert seq.max_active == 1 and conc.max_active > 1
    assert_same_arrays(saved_arrays(cells), saved_arrays(cells3))
    assert set(timings["experiments"]) == {c.id for c in cells3}
    assert len(snaps) == len(cells3)  # a snapshot after every saved cell
    # Each row's demonstrations are made by the cell that makes them one at a time ...
    assert conc.demos_made == seq.demos_made
    order = {}
    for i, (what, cid) in enumerate(conc.log):
        order[what, cid] = i
    for c in cells3:
        if c.source is not None:  # ... and a transfer starts after its source ended.
            assert order["start", c.id] > order["end", c.source.id]


def test_failed_demos_skip_their_row_as_one_at_a_time(tmp_path, monkeypatch):
    profile = two_object_profile()
    results = {}
    for jobs in (1, 2):
        fake = FakeLearn(profile, fail_demos={"active/pitcher"})
        cells, _, failures, _ = run_bench(profile, tmp_path / f"j{jobs}", jobs, fake,
                                          monkeypatch)
        results[jobs] = failures, saved_arrays(cells), [e for e in fake.log if e[0] == "start"]
    (f1, a1, s1), (f2, a2, s2) = results[1], results[2]
    assert f1 == f2
    assert f1["active/pitcher/random_walk"].startswith("ValueError: no demonstrated grasp")
    assert f1["active/pitcher/kameleon_darting_biased"].startswith(
        "skipped: demonstrations failed in active/pitcher/random_walk")
    assert f1["transfer/transfer_a/tall_pitcher/target"].startswith("skipped: its source")
    assert_same_arrays(a1, a2)
    plates = {c.id for c in cells if c.obj in ("plate", "soup_plate", "platter")}
    assert set(a2) == plates  # the other rows still ran
    assert sorted(s1) == sorted(s2)  # the same cells ran (the failed row's owner only)


def test_an_unexpected_error_is_raised(tmp_path, monkeypatch):
    profile = tiny_profile()

    def broken(cell, *a, **k):
        raise RuntimeError(f"broken {cell.id}")

    with pytest.raises(RuntimeError, match="broken active/pitcher/random_walk"):
        run_bench(profile, tmp_path, 2, broken, monkeypatch)


class FakeSims(NoSims):
    chains, compile_s = 2, {}


@pytest.fixture
def thread_cluster(monkeypatch):
    """A Dask cluster of 2 single-threaded workers in this process (so the fake learning run
    reaches them), whose compiled trials are fakes: the address of its scheduler."""
    from dask.distributed import LocalCluster

    monkeypatch.setattr(run, "_WORKER_SIMS", {})
    monkeypatch.setattr(run, "Simulators", lambda backend, chains: FakeSims())
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def test_dask_tasks_save_the_sequential_results_and_failures(tmp_path, monkeypatch,
                                                              thread_cluster):
    profile = two_object_profile()
    seq = FakeLearn(profile, fail_demos={"active/pitcher"})
    cells, _, fail1, _ = run_bench(profile, tmp_path / "seq", 1, seq, monkeypatch)
    conc = FakeLearn(profile, fail_demos={"active/pitcher"})
    cells2, timings, fail2, snaps = run_bench(profile, tmp_path / "dask", None, conc,
                                              monkeypatch, workers="process", sims=FakeSims(),
                                              scheduler=thread_cluster)
    assert fail2 == fail1 and fail1["active/pitcher/random_walk"].startswith("ValueError")
    assert_same_arrays(saved_arrays(cells), saved_arrays(cells2))
    assert set(timings["experiments"]) == set(saved_arrays(cells2))
    assert len(snaps) == len(saved_arrays(cells2)) + 1  # after each saved cell, the failed one
    assert conc.demos_made == seq.demos_made
    order = {(what, cid): i for i, (what, cid) in enumerate(conc.log)}
    for c in cells2:
        if c.source is not None and ("start", c.id) in order:
            assert order["start", c.id] > order["end", c.source.id]


def test_a_lost_task_is_the_cell_failure(tmp_path, monkeypatch, thread_cluster):
    # A task that fails on the cluster itself (as when its worker dies each time Dask tries
    # it) fails its cell and skips its dependants; the other cells are saved.
    profile = tiny_profile()
    real = run._dask_cell

    def lost(c, *args):
        if c.column == "kameleon_darting_biased":  # the transfers' source
            raise OSError("worker gone (test)")
        return real(c, *args)

    monkeypatch.setattr(run, "_dask_cell", lost)
    cells, _, failures, _ = run_bench(profile, tmp_path, 2, FakeLearn(profile), monkeypatch,
                                      workers="process", sims=FakeSims(),
                                      scheduler=thread_cluster)
    lost = "active/pitcher/kameleon_darting_biased"
    assert failures.pop(lost) == "WorkerLost: OSError: worker gone (test)"
    assert sorted(failures) == [c.id for c in cells if c.table == "transfer"]
    assert all(f == f"skipped: its source {lost} failed" for f in failures.values())
    assert set(saved_arrays(cells)) == {c.id for c in cells if c.table == "active"} - {lost}


def test_cell_demos_are_computed_once_under_concurrency(tmp_path, monkeypatch):
    profile = tiny_profile()
    cells = plan.plan(profile, tmp_path)
    calls, ready = [], []

    class Obj:
        content_hash = "0" * 16

    class Sim:
        obj, scene = Obj(), None

    def demonstrations(obj, num, seed, trial, params):
        calls.append(seed)
        time.sleep(0.2)  # the other threads arrive meanwhile
        poses = np.tile(np.array([0, 0, 0.1, 1, 0, 0, 0], np.float32), (num, 1))
        return Demos(poses, None)

    monkeypatch.setattr(run.learn, "demonstrations", demonstrations)
    monkeypatch.setattr(run, "demo_result_arrays", lambda results: {})
    monkeypatch.setattr(run, "demo_results_from_arrays", lambda arrays: None)
    got = []
    threads = [threading.Thread(target=lambda c=c: got.append(run.cell_demos(
        c, profile, "mujoco", lambda name: Sim(), on_ready=lambda: ready.append(1))))
        for c in cells[:3]]  # the three active cells of one row
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and len(got) == 3 and len(ready) == 3
    for d in got:
        np.testing.assert_array_equal(np.asarray(d.poses), np.asarray(got[0].poses))
    assert len(list((tmp_path / "runs" / "demos").rglob("*.npz"))) == 1


def test_cli_jobs_flag():
    from jaxgrasp.bench import cli

    assert cli.parse_args(["--jobs", "3"]).jobs == 3
    assert cli.parse_args([]).jobs is None  # the default is chosen in main
    with pytest.raises(SystemExit):
        cli.parse_args(["--jobs", "0"])
    assert cli.main(["--jobs", "2", "--distributed", "--out", "/nonexistent/x"]) == 2


# --------------------------------------------------------------------------------------------
# The real learning runs.


@pytest.mark.slow  # 3-8 min on 2 busy cores: the tiny profile in this process, then 2 workers
def test_real_runs_with_two_worker_processes_equal_one_at_a_time(tmp_path):
    from jaxgrasp.learn.pipeline import simulator_batch

    profile = tiny_profile()
    sims = run.Simulators("mujoco", simulator_batch(profile.chains, None))
    arrays, fails = {}, {}
    for jobs in (1, 2):
        cells = plan.plan(profile, tmp_path / f"j{jobs}")
        timings, failures = {"experiments": {}}, {}
        run.run_experiments(cells, profile, "mujoco", sims, timings, failures, resume=False,
                            quiet=True, devices=None, snapshot=lambda complete: None,
                            log=lambda *a: None, jobs=jobs)
        arrays[jobs], fails[jobs] = saved_arrays(cells), failures
    assert fails[1] == fails[2] == {}
    assert len(arrays[1]) == len(plan.plan(profile, tmp_path))
    assert_same_arrays(arrays[1], arrays[2])
