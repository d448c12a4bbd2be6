"""One process compiles a learning run once: runs that differ in seed, iteration count or
arrays (sketch, demos) reuse the trial and sampler compiled by the first, and a run on another
object reuses its samplers and the trial's stages.

``jg.learn.active`` without ``trial`` runs on the process's shared Simulator of the object
(``jaxgrasp.learn.sim.shared_simulator``); ``box_sim`` is that same simulator, so these runs
also reuse what ``kd_result`` compiled.
"""

import dataclasses
from contextlib import contextmanager

import jax
import numpy as np
import pytest
from jax import monitoring

import jaxgrasp as jg
from jaxgrasp.learn import pipeline
from jaxgrasp.learn import sim as sim_module
from jaxgrasp.mcmc.sample import scan_lengths

#: Recorded once per XLA program built (compiled, or read from the persistent cache).
BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
ARRAYS = ("positions", "proposals", "outcomes", "epsilons", "accepted", "is_jump",
          "initial_positions", "modes", "sketch_points")


@contextmanager
def programs_built():
    """The names of the XLA programs built inside the block (a list filled as they are)."""
    names = []

    def listen(event, secs, **kwargs):
        if event == BACKEND_COMPILE:
            names.append(kwargs.get("fun_name"))

    monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        monitoring.unregister_event_duration_listener(listen)


def test_runs_without_a_trial_share_one_simulator(box, box_sim):
    assert sim_module.as_simulator(box, batch_size=box_sim.batch_size) is box_sim
    assert sim_module.as_simulator(box, batch_size=8) is not box_sim
    # another batch size: its own simulator around the same trial (the same JAX stages)
    assert sim_module.as_simulator(box, batch_size=8).trial is box_sim.trial
    bigger = jg.objects.make_box(half_extents=(0.03, 0.03, 0.06))
    assert sim_module.scene_key(bigger) != sim_module.scene_key(box)


def test_second_run_compiles_nothing_and_repeats_the_first(box, box_sim, small_params,
                                                           kd_result):
    kw = dict(method="kameleon_darting", sketch="biased", chains=box_sim.batch_size,
              params=small_params, demos=kd_result.demos, progress=False)
    # kd_result's run again, through the shared simulator: its arrays bit for bit
    again = jg.learn.active(box, seed=0, **kw)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(again, name), getattr(kd_result, name), name)
    # a new seed (a new biased sketch) and fewer iterations: nothing new to compile
    with programs_built() as built:
        other = jg.learn.active(box, seed=1, iterations=small_params.iterations - 10, **kw)
    assert built == []
    assert other.positions.shape[0] == small_params.num_steps - 10
    assert not np.array_equal(other.sketch_points, kd_result.sketch_points)


def test_a_new_object_compiles_nothing(box, box_sim, small_params, kd_result):
    """A second, different object in the same process: its demo search, sketch and chains
    reuse the samplers and the trial's stages compiled for the box (the simulator's id, the
    object's padded hulls and piece poses, its friction, COM and radius are arguments): it
    builds no program. The companion: a program built in the block is seen."""
    other = jg.objects.make_box(half_extents=(0.03, 0.03, 0.06))
    with programs_built() as built:
        result = jg.learn.active(other, method="kameleon_darting", sketch="biased",
                                 chains=box_sim.batch_size, seed=0, params=small_params,
                                 progress=False)
    assert result.object_name == other.name
    assert built == []
    with programs_built() as built:
        jax.jit(lambda x: x * 3 + 1)(np.arange(5, dtype=np.float32) + 0.5)
    assert built == ["jit(<lambda>)"]


def test_another_symmetry_compiles_nothing(box, box_sim, small_params, kd_result):
    """Objects on offset axes share one sampler whatever their own moves: 3-fold turns,
    none, 6-fold turns (the moves' kinds and numbers are arrays, absent ones never-picked
    groups). The first run may compile; the others build no program."""
    kw = dict(method="kameleon_darting", sketch="biased", chains=box_sim.batch_size, seed=0,
              demos=kd_result.demos, progress=False)
    runs = []
    for spec in ("turns:3@0.003,0.001", "none@0.004,-0.002", "turns:6@-0.002,0.001"):
        params = dataclasses.replace(small_params, symmetry=spec)
        with programs_built() as built:
            runs.append(jg.learn.active(box, params=params, **kw).positions)
        assert built == [] or spec.startswith("turns:3"), (spec, built)
    assert not np.array_equal(runs[1], runs[2])


@pytest.mark.slow  # two sampler compiles; `tests/mcmc/test_sample.py -k precompile` is the unit
def test_the_sampler_compiles_while_the_demos_are_made(box, box_sim, small_params,
                                                      kd_result, monkeypatch):
    """A run compiles its sampler in a thread during its setup: none of it is left for the
    chains (another burn-in length is another program). The companion: without the thread
    the chains compile it."""
    real = pipeline.run_chains
    for burn_in, ahead in ((20, True), (30, False)):  # whole chunks: no shorter last scan
        if not ahead:
            monkeypatch.setattr(pipeline, "_compile_ahead", lambda *args: None)
        seen = []

        def chains(*args, seen=seen, **kwargs):
            with programs_built() as built:
                out = real(*args, **kwargs)
            seen.extend(built)
            return out

        monkeypatch.setattr(pipeline, "run_chains", chains)
        jg.learn.active(box, method="kameleon_darting", sketch="biased",
                        chains=box_sim.batch_size, seed=0, demos=kd_result.demos,
                        params=dataclasses.replace(small_params, burn_in=burn_in),
                        progress=False)
        assert ("jit(_scan_steps)" in seen) is not ahead, (burn_in, seen)


def test_scan_lengths_of_a_short_last_chunk():
    assert scan_lengths(10, 10) == [10]
    assert scan_lengths(7, 10) == [4, 2, 1]
    assert scan_lengths(8, 10) == [8]
    assert {n for r in range(1, 10) for n in scan_lengths(r, 10)} == {1, 2, 4, 8}
