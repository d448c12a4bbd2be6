"""A dataset learned for real: on a Dask cluster of 2 worker processes, on a scheduler and a
worker started apart (as on other hosts), and killed with ``kill -9`` then resumed, it gives
the index rows and grasp files of a one-process run."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from jaxgrasp.learn.files.export import load_grasps

REPO = Path(__file__).resolve().parents[2]
TINY = ["--chains", "2", "--iterations", "20", "--burn-in", "2", "--robust-tries", "2",
        "--quiet"]
#: A backstop only: how long a scheduler may take to write its address (it does in seconds).
READY_WAIT_S = 600.0


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(
        os.pathsep)
    return env


def _learn(meshes, out, *extra):
    cmd = [sys.executable, "-m", "jaxgrasp.learn", str(meshes), "--out", str(out), *TINY,
           *extra]
    return subprocess.run(cmd, cwd=REPO, env=_env(), capture_output=True, text=True,
                          timeout=1800)


def _rows(out: Path) -> list:
    rows = json.loads((out / "index.json").read_text())["objects"]
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


def _same_grasps(a: Path, b: Path, rows: list) -> None:
    for row in rows:
        if row["status"] == "ok":
            ga, gb = (load_grasps(d / row["object"] / "grasps.h5") for d in (a, b))
            np.testing.assert_array_equal(ga.grasps, gb.grasps)
            np.testing.assert_array_equal(ga.robustness, gb.robustness)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("meshes")
    trimesh.creation.cylinder(radius=0.03, height=0.1).export(folder / "can.stl")
    trimesh.creation.box(extents=[0.05, 0.06, 0.08]).export(folder / "box.stl")
    (folder / "bad.stl").write_text("solid nothing\nendsolid nothing\n")  # no triangles
    return folder


@pytest.fixture(scope="module")
def reference(meshes, tmp_path_factory):
    out = tmp_path_factory.mktemp("one_process") / "dataset"
    res = _learn(meshes, out, "--workers", "1")
    assert res.returncode == 1, res.stderr[-3000:]  # the bad mesh failed, the rest learned
    rows = _rows(out)
    assert [(r["object"], r["status"]) for r in rows] == [
        ("bad", "failed"), ("box", "ok"), ("can", "ok")]
    assert "bad.stl" in rows[0]["error"] and rows[1]["trials"] == 2 * 22
    return out


@pytest.mark.slow
def test_two_worker_processes_give_the_one_process_dataset(meshes, reference, tmp_path):
    out = tmp_path / "dataset"
    res = _learn(meshes, out, "--workers", "2")
    assert res.returncode == 1, res.stderr[-3000:]
    assert _rows(out) == _rows(reference)
    _same_grasps(reference, out, _rows(out))


@pytest.mark.slow
def test_sigkill_then_resume_gives_the_one_process_dataset(meshes, reference, tmp_path,
                                                          kill_at_second_run):
    out = tmp_path / "dataset"
    cmd = [str(meshes), "--out", str(out), *TINY, "--workers", "1"]
    status = kill_at_second_run("jaxgrasp.learn.__main__", cmd, cwd=REPO, env=_env())
    assert status == -signal.SIGKILL, "the dataset finished before it could be killed"
    killed = {r["object"]: r["status"] for r in json.loads(
        (out / "index.json").read_text())["objects"]}
    assert killed == {"bad": "failed", "box": "ok", "can": "pending"}
    assert (out / "can" / "run" / "checkpoint.npz").exists()

    res = _learn(meshes, out, "--workers", "1")
    assert res.returncode == 1, res.stderr[-3000:]
    assert "2 of 3 objects learned (1 before)" in res.stdout
    assert _rows(out) == _rows(reference)
    _same_grasps(reference, out, _rows(out))


@pytest.fixture
def scheduler_and_worker(tmp_path):
    """``dask scheduler`` and ``dask worker`` (one single-threaded worker process under its
    nanny), each a process of its own on localhost, as the README starts them on several
    hosts: the scheduler's address. Both are killed afterwards."""
    from dask.distributed import Client

    file, procs = tmp_path / "scheduler.json", []

    def start(*args):
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", *args], cwd=tmp_path, env=_env(),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))

    try:
        # Port 0: the scheduler takes a free port and writes its address to the file.
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(file))
        deadline = time.monotonic() + READY_WAIT_S
        while not file.exists() and procs[0].poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert file.exists(), "the scheduler did not start"
        address = json.loads(file.read_text())["address"]
        start("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-dashboard",
              "--local-directory", str(tmp_path / "worker"))
        with Client(address) as client:
            client.wait_for_workers(1, timeout=READY_WAIT_S)
        yield address
    finally:
        for proc in procs:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)  # the nanny's worker too (same session)
            proc.wait(timeout=60)


@pytest.mark.slow
def test_a_scheduler_and_worker_apart_give_the_one_process_dataset(meshes, reference, tmp_path,
                                                                   scheduler_and_worker):
    out = tmp_path / "dataset"
    res = _learn(meshes, out, "--scheduler", scheduler_and_worker)
    assert res.returncode == 1, res.stderr[-3000:]
    assert _rows(out) == _rows(reference)
    _same_grasps(reference, out, _rows(out))
