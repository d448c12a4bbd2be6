"""Checkpoint/resume: an interrupted run resumes and ends bit-identical to an uninterrupted one."""

import os
import signal
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn import chains

ARRAYS = ("positions", "proposals", "outcomes", "epsilons", "accepted", "is_jump",
          "initial_positions", "modes", "sketch_points")


def assert_same_run(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.demos.poses, b.demos.poses)


def interrupt_after(monkeypatch, step):
    """Make the checkpoint writer raise KeyboardInterrupt (a Ctrl-C) once ``step`` is saved."""
    real = chains.save_checkpoint
    calls = []

    def save_then_interrupt(ckpt, done, hist, state):
        real(ckpt, done, hist, state)
        calls.append(done)
        if done >= step:
            raise KeyboardInterrupt

    monkeypatch.setattr(chains, "save_checkpoint", save_then_interrupt)
    return calls


def run_interrupted(monkeypatch, tmp_path, kw, step):
    calls = interrupt_after(monkeypatch, step)
    with pytest.raises(KeyboardInterrupt):
        jg.learn.active(**kw, checkpoint_dir=tmp_path, checkpoint_every=10)
    monkeypatch.undo()
    assert calls and calls[-1] == step
    return jg.learn.active(**kw, checkpoint_dir=tmp_path, checkpoint_every=10)


@pytest.mark.parametrize("method", ["random_walk", "kameleon_darting"])
def test_resume_fake_trial(monkeypatch, tmp_path, box, fake_sim, small_params, method):
    kw = dict(obj=box, method=method, sketch="biased", chains=4, seed=5, params=small_params,
              trial=fake_sim, progress=False)
    reference = jg.learn.active(**kw)
    resumed = run_interrupted(monkeypatch, tmp_path, kw, step=20)
    assert_same_run(resumed, reference)
    # A finished directory is just loaded again.
    again = jg.learn.active(**kw, checkpoint_dir=tmp_path, checkpoint_every=10)
    assert_same_run(again, reference)


def test_checkpoint_of_another_run_refused(tmp_path, box, fake_sim, small_params):
    kw = dict(method="random_walk", chains=4, params=small_params, trial=fake_sim,
              progress=False, checkpoint_dir=tmp_path, checkpoint_every=10)
    jg.learn.active(box, seed=1, **kw)
    with pytest.raises(ValueError, match="another run.*seed"):
        jg.learn.active(box, seed=2, **kw)


def test_resume_real_physics(monkeypatch, tmp_path, box, box_sim, small_params, kd_result):
    """The shared Kameleon run (real MJX trial), interrupted after 30 of 50 steps."""
    kw = dict(obj=box, method="kameleon_darting", sketch="biased", chains=4, seed=0,
              params=small_params, trial=box_sim, progress=False)
    resumed = run_interrupted(monkeypatch, tmp_path, kw, step=30)
    assert_same_run(resumed, kd_result)


SCRIPT = textwrap.dedent("""
    import os, sys
    import jaxgrasp as jg
    sys.path.insert(0, os.path.dirname(sys.argv[2]))
    from conftest import make_fake_trial, SMALL
    jg.enable_compilation_cache()
    box = jg.objects.make_box()
    sim = jg.learn.Simulator(box, trial=make_fake_trial(), batch_size=4)
    from jaxgrasp.learn import chains as A
    real = A.save_checkpoint
    def save(ckpt, done, hist, state):
        real(ckpt, done, hist, state)
        print("saved", done, flush=True)
        if os.environ.get("HANG_AT") == str(done):
            import time; time.sleep(600)
    A.save_checkpoint = save
    r = jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=9,
                        params=jg.learn.LearnParams(**SMALL), trial=sim, progress=False,
                        checkpoint_dir=sys.argv[1], checkpoint_every=10)
    print("done", r.counts.sum(), flush=True)
""")


@pytest.mark.slow
def test_resume_after_sigkill(tmp_path, box, fake_sim, small_params, repo_root):
    """A process killed with SIGKILL right after a checkpoint resumes bit-identically."""
    script = tmp_path / "run.py"
    script.write_text(SCRIPT)
    conftest = repo_root / "tests" / "learn" / "conftest.py"
    ckpt = tmp_path / "ckpt"
    env = {**os.environ, "HANG_AT": "30"}
    proc = subprocess.Popen([sys.executable, str(script), str(ckpt), str(conftest)], env=env,
                            stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        if line.strip() == "saved 30":
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not (ckpt / "result.json").exists()
    out = subprocess.run([sys.executable, str(script), str(ckpt), str(conftest)], check=True,
                         capture_output=True, text=True, env=os.environ)
    assert "saved 40" in out.stdout and "saved 10" not in out.stdout
    resumed = jg.learn.load(ckpt, box)
    reference = jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4,
                                seed=9, params=small_params, trial=fake_sim, progress=False,
                                checkpoint_every=10)
    assert_same_run(resumed, reference)


def test_ctrl_c_inside_the_physics_resumes(tmp_path, box, small_params, fake_trial):
    """KeyboardInterrupt raised while a trial runs (host callback) stops the run as a
    KeyboardInterrupt; the next call resumes from the last checkpoint, bit-identically."""
    calls = {"n": 0, "stop_at": None}

    def interruptible(grasps):  # a host-level trial (numpy in and out), like MuJoCo C
        calls["n"] += 1
        if calls["n"] == calls["stop_at"]:
            raise KeyboardInterrupt
        return jax.tree.map(np.asarray, fake_trial(np.asarray(grasps)))

    sim = jg.learn.Simulator(box, trial=interruptible, batch_size=4)
    kw = dict(obj=box, method="kameleon_darting", sketch="random", chains=4, seed=11,
              params=small_params, trial=sim, progress=False, checkpoint_every=10)
    reference = jg.learn.active(**kw)
    calls.update(n=0, stop_at=None)
    calls["stop_at"] = 30  # demos + init + ~25 steps: inside the main run
    with pytest.raises(KeyboardInterrupt):
        jg.learn.active(**kw, checkpoint_dir=tmp_path)
    assert (tmp_path / "checkpoint.npz").exists() and not (tmp_path / "result.json").exists()
    calls["stop_at"] = None
    assert_same_run(jg.learn.active(**kw, checkpoint_dir=tmp_path), reference)


def test_corrupt_checkpoint_is_a_clear_error(tmp_path, box, fake_sim, small_params):
    kw = dict(method="random_walk", chains=4, seed=1, params=small_params, trial=fake_sim,
              progress=False, checkpoint_dir=tmp_path, checkpoint_every=10)
    jg.learn.active(box, **kw)
    (tmp_path / "result.json").unlink()
    (tmp_path / "checkpoint.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="checkpoint"):
        jg.learn.active(box, **kw)
