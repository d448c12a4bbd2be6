"""``jg.learn.Cohort``: learning runs at once, their trial calls merged into one host call.

A cohort needs one CPU device per member (plus device 0), and the device count is fixed when
JAX starts, so the runs are in a subprocess with ``--xla_force_host_platform_device_count``.
The analytic fake trial is elementwise per row, so a merged run must give exactly the runs
alone; a cohort that hands rows to the wrong member (the companion) must not.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.bench import cli

WORKER = textwrap.dedent(
    """
    import sys
    from functools import partial
    import numpy as np
    sys.path.insert(0, sys.argv[2])
    from conftest import SMALL, make_fake_trial
    import jaxgrasp as jg
    from jaxgrasp.learn import cohort as cohort_mod

    WAIT_FOR_ALL = 3600.0
    box = jg.objects.make_box()
    params = jg.learn.LearnParams(**SMALL)
    # Two members, one per method: each member's samplers compile again on its own device.
    runs = [("kameleon_darting", 0), ("random_walk", 1)]

    def tasks(sim):
        return [partial(jg.learn.active, box, method=m, sketch="random", chains=4, seed=s,
                        params=params, trial=sim, progress=False) for m, s in runs]

    # One simulator for all three phases: the samplers reach it by a host callback, so they
    # stay out of the persistent compilation cache, and a new simulator compiles them again.
    sim = jg.learn.Simulator(box, trial=make_fake_trial(), batch_size=4)

    out = {}
    for i, r in enumerate(f() for f in tasks(sim)):
        out[f"solo{i}"] = r.outcomes
        out[f"solo_prop{i}"] = r.proposals
    # Calls wait for every member (no deadline in practice), so what merges does not depend on
    # how busy the machine is.
    c = jg.learn.Cohort(len(runs), max_wait=WAIT_FOR_ALL)
    for i, r in enumerate(c.run(tasks(c.attach(sim)))):
        out[f"cohort{i}"] = r.outcomes
        out[f"cohort_prop{i}"] = r.proposals
    out["sizes"] = np.array(sorted(c.sizes.elements()))

    # Companion: a cohort that hands each run the rows of the next run of its merged call.
    groups = cohort_mod.Cohort._simulate_groups

    def rotated(batch):
        groups(batch)
        res = [r.result for r in batch]
        for r, x in zip(batch, res[1:] + res[:1]):
            r.result = x

    cohort_mod.Cohort._simulate_groups = staticmethod(rotated)
    c = jg.learn.Cohort(len(runs), max_wait=WAIT_FOR_ALL)
    for i, r in enumerate(c.run(tasks(c.attach(sim)))):
        out[f"swapped{i}"] = r.outcomes
    np.savez(sys.argv[1], **out)
    """
)


@pytest.fixture(scope="module")
def cohort_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("cohort") / "runs.npz"
    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"
    proc = subprocess.run(
        [sys.executable, "-c", WORKER, str(out), str(Path(__file__).parent)],
        env={**os.environ, "XLA_FLAGS": flags.strip()}, capture_output=True, text=True,
        timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    with np.load(out) as z:
        return dict(z)


@pytest.mark.slow  # the cohort is an option, not the default; ~70 s of compiling in a subprocess
def test_merged_runs_equal_the_runs_alone(cohort_runs):
    # One test for the three checks of the one subprocess: split over pytest-xdist's workers,
    # each worker would run that subprocess again (~45 s of CPU).
    for i in range(2):
        np.testing.assert_array_equal(cohort_runs[f"cohort{i}"], cohort_runs[f"solo{i}"])
        np.testing.assert_array_equal(cohort_runs[f"cohort_prop{i}"],
                                      cohort_runs[f"solo_prop{i}"])

    # The calls were merged: 4 chains per run, so a call of more than 4 grasps came from
    # both runs.
    sizes = cohort_runs["sizes"]
    assert sizes.max() >= 8
    assert np.mean(sizes > 4) > 0.5

    # The companion: the same comparison fails for a merge that hands rows to the wrong run.
    assert any(not np.array_equal(cohort_runs[f"swapped{i}"], cohort_runs[f"solo{i}"])
               for i in range(2))


def test_too_few_cpu_devices_is_a_clear_error():
    with pytest.raises(ValueError, match="xla_force_host_platform_device_count"):
        jg.learn.Cohort(64)
    with pytest.raises(ValueError, match="positive int"):
        jg.learn.Cohort(0)


def test_real_trial_rows_do_not_depend_on_the_batch(box_sim):
    # What a merged call relies on: a grasp's outcome and epsilon are the same whatever else
    # is in its batch (checked on MuJoCo C, the backend whose calls are merged).
    # Top-down grasps on the 6 x 6 x 10 cm box around tests/physics' GOOD: holds, slips, misses.
    rng = np.random.default_rng(0)
    g = np.tile(np.array([0.0, 0.0, 0.085, 0.0, 1.0, 0.0, 0.0], np.float32), (20, 1))
    g[:, :3] += rng.uniform(-0.01, 0.01, (20, 3)).astype(np.float32)
    g[:, 3:] += rng.normal(0.0, 0.1, (20, 4)).astype(np.float32)
    alone = box_sim(g[:4])
    merged = box_sim.simulate_now(np.concatenate([g[4:], g[:4]]), merged=True)
    assert np.any(alone.epsilon > 0)  # the compared rows made contact
    np.testing.assert_array_equal(merged.outcome[16:], alone.outcome)
    np.testing.assert_allclose(merged.epsilon[16:], alone.epsilon, rtol=1e-5, atol=1e-7)


def test_bench_workers_flag():
    assert cli.parse_args(["--jobs", "3", "--workers", "cohort"]).workers == "cohort"
    assert cli.parse_args([]).workers == "process"
    assert cli.main(["--jobs", "2", "--workers", "cohort", "--devices", "2",
                     "--out", "/nonexistent/x"]) == 2
