"""Interruptions lose nothing: ``kill -9`` of ``python -m jaxgrasp.bench``, then ``--resume``,
gives the tables of an uninterrupted run (the full set of kills: ``benchmarks/kill_resume.py``).
"""

import signal
import subprocess
from types import SimpleNamespace

import pytest


@pytest.fixture(scope="module")
def kr(load_benchmark):
    return load_benchmark("kill_resume")


@pytest.mark.slow
def test_sigkill_then_resume_reproduces_the_tables(tmp_path, kr, kill_at_second_run):
    # Cheapest run with every cell type and learn checkpoints: 5 experiments x 2 chains x 8
    # steps, a checkpoint every 2 steps.
    args = SimpleNamespace(profile="smoke", objects="pitcher", backend="mujoco", seed=0,
                           checkpoint_every=2)
    extra = ["--chains", "2", "--iterations", "4", "--burn-in", "4"]
    ref, out = tmp_path / "reference", tmp_path / "interrupted"
    subprocess.run(kr.bench_cmd(ref, args) + extra, cwd=kr.REPO, env=kr._env(), check=True,
                   capture_output=True, timeout=1200)

    # Kill right after the second experiment's first checkpoint: one finished experiment
    # and one mid-way. The bench says when it is there (and waits), so the kill does not race
    # the run, however busy the machine.
    cmd = kr.bench_cmd(out, args) + extra
    status = kill_at_second_run("jaxgrasp.bench", cmd[3:], cwd=kr.REPO, env=kr._env())
    assert status == -signal.SIGKILL, "the bench finished before it could be killed"
    killed_at = kr.progress_of(out)
    assert all(isinstance(s, int) for s in killed_at["checkpoint_steps"].values()), killed_at

    res = subprocess.run(kr.bench_cmd(out, args, resume=True) + extra, cwd=kr.REPO,
                         env=kr._env(), capture_output=True, text=True, timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    cmp = kr.compare(ref, out)
    assert cmp["match"], cmp
    assert cmp["experiments"] == 5
    assert kr.check_files(out) == []
    assert kr._tmp_files(out) == []
    # The killed experiment continued from its checkpoint, it was not set aside and rerun.
    assert not (out / "runs" / ".stale").exists()
