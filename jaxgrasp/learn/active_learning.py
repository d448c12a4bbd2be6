"""Active learning of grasps (paper §4, experiments 1-3).

Protocol of one run: make ``num_demos`` demonstrated grasps (the GDMC modes), build the rough
sketch, start the chains at the demos (chain ``c`` at demo ``c mod m``) and run
``burn_in + iterations`` steps; Kameleon adapts during the burn-in. Every proposal is one
physics trial and is counted, burn-in included, as in the paper's tables (1100 proposals per
run).

``method="antipodal"`` is the field's standard sampler instead of a chain: as many
collision-free antipodal grasps (:mod:`jaxgrasp.learn.setup.antipodal`) as the chains would
make proposals, each simulated once, recorded in the same history layout (step-major, one
row of ``chains`` grasps per step), so every report of a :class:`LearnResult` applies.
"""

import time

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxgrasp.learn import pipeline
from jaxgrasp.learn.algorithm import METHODS
from jaxgrasp.learn.chains import DEFAULT_CHUNK, empty_history
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.inputs import (
    check_chains,
    check_every,
    check_seed,
    resolve_object,
    resolve_params,
)
from jaxgrasp.learn.setup.antipodal import antipodal_grasps, placement_collisions
from jaxgrasp.learn.setup.demos import Demos, demonstrations
from jaxgrasp.learn.setup.sketch import biased_sketch, random_sketch
from jaxgrasp.learn.sim import as_simulator, run_backend
from jaxgrasp.physics import GripperParams, Outcome

__all__ = ["active", "ACTIVE_METHODS", "SKETCHES"]

SKETCHES = ("random", "biased")
#: The samplers of ``active``: the chains of :data:`~jaxgrasp.learn.algorithm.METHODS` and the
#: antipodal sampler.
ACTIVE_METHODS = (*METHODS, "antipodal")


def active(obj, *, method="kameleon_darting", sketch="biased", chains=4, iterations=None,
           burn_in=None, seed=0, params=None, backend="auto", checkpoint_dir=None,
           checkpoint_every=None, progress=True, trial=None, devices=None,
           demos=None) -> LearnResult:
    """Active learning of grasps for a known object (paper experiments 1-3).

    Parameters
    ----------
    obj : GraspObject, Scene or str
    method : {"random_walk", "kameleon_darting", "antipodal"}
        Experiment 1 (baseline), Kameleon MCMC combined with GDMC jumps, or the antipodal
        sampler: ``chains * (burn_in + iterations)`` seeded collision-free antipodal grasps,
        each simulated once (no demos needed: the result's demos are ``demos`` or none; no
        chain, so every proposal counts as accepted; ``robust_tries`` and ``devices`` do not
        apply).
    sketch : {"random", "biased"}
        Kameleon's rough sketch: uniformly random poses (experiment 2) or the proposals of a
        random-walk run from the demos (experiment 3). Ignored by the other methods.
    chains : int
        Independent chains, run in parallel (vmapped): one batched trial per step.
    iterations, burn_in : int, optional
        Override ``params.iterations`` / ``params.burn_in`` (Table I: 1000 and 100).
    seed : int
        Determines demos, sketch and chains.
    params : LearnParams, optional
    backend : str
        Physics backend for ``jg.physics.make_trial``: ``"auto"`` (MuJoCo C when JAX runs on
        the CPU, MJX on an accelerator; with a Simulator as ``trial``, its backend),
        ``"mjx"`` or ``"mujoco"``. The result and checkpoint record the resolved name.
    checkpoint_dir : path, optional
        Save setup and chain state there every ``checkpoint_every`` steps (default 10); a
        call with the same arguments and directory resumes (or returns the finished result).
    checkpoint_every : int, optional
    progress : bool
        Show tqdm progress bars (the demo search, the chains).
    trial : Simulator or callable, optional
        A prebuilt trial of ``obj`` (shares compiled physics across runs).
    devices : None, "all", int, devices or Mesh, optional
        Shard the chains of the main run over these devices (``jg.mcmc.sample(devices=)``).
        A traceable trial (MJX) is then traced into the sampler so every device runs the
        rollouts of its own chains; a host-level trial stays a host callback, called once per
        device shard. Demos and the sketch run are not sharded. Multi-host: see
        ``jg.mcmc.sharding``.
    demos : Demos, optional
        Precomputed demonstrations on ``obj`` (as ``jg.learn.demonstrations(obj,
        num=params.num_demos, seed=seed, params=params)``); computed when None.

    Returns
    -------
    LearnResult
    """
    backend = run_backend(backend, trial)
    if method not in ACTIVE_METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {ACTIVE_METHODS}")
    if sketch not in SKETCHES:
        raise ValueError(f"unknown sketch {sketch!r}; expected one of {SKETCHES}")
    params = resolve_params(params, iterations=iterations, burn_in=burn_in)
    seed, chains = check_seed(seed), check_chains(chains)
    check_every(checkpoint_every)
    obj = resolve_object(obj)
    if demos is not None:
        demos = pipeline.check_demos(demos)
    sketch_kind = sketch if method == "kameleon_darting" else "none"
    config = {"workflow": "active", "object": obj.name, "object_hash": obj.content_hash,
              "method": method, "sketch": sketch_kind, "chains": chains, "seed": seed,
              "backend": backend, "params": params.to_dict()}
    if method == "antipodal":
        if devices is not None:
            raise ValueError("method='antipodal' simulates on the host simulator; devices "
                             "does not apply")
        return _antipodal(obj, config, chains=chains, seed=seed, params=params,
                          backend=backend, trial=trial, demos=demos,
                          checkpoint_dir=checkpoint_dir, progress=progress)

    def make_setup(sim, checkpoint):
        run_demos = demos
        if run_demos is None:
            run_demos = demonstrations(obj, num=params.num_demos, seed=seed, trial=sim,
                                       params=params, progress=progress,
                                       checkpoint=checkpoint)
        key = jax.random.fold_in(jax.random.key(seed), 1)
        if method == "random_walk":
            return run_demos, np.zeros((0, 7), np.float32)
        if sketch == "random":
            return run_demos, random_sketch(sim.scene or obj, key, params.sketch_size)
        return run_demos, biased_sketch(obj, key, params.sketch_size, demos=run_demos,
                                        params=params, chains=chains, trial=sim,
                                        progress=progress)

    desc = f"{obj.name} {method}" + (f" ({sketch} sketch)" if method == "kameleon_darting"
                                     else "")
    record = {"workflow": "active", "sketch": sketch_kind,
              "modes_kind": "demos" if method == "kameleon_darting" else "none"}
    return pipeline.run(obj, config, make_setup, method=method, chains=chains, seed=seed,
                        stream=2, params=params, backend=backend, record=record, trial=trial,
                        devices=devices, checkpoint_dir=checkpoint_dir,
                        checkpoint_every=checkpoint_every, progress=progress, desc=desc)


def _antipodal(obj, config, *, chains, seed, params, backend, trial, demos, checkpoint_dir,
               progress) -> LearnResult:
    """The antipodal sampler's run: candidates drawn (placement collisions dropped without a
    rollout), simulated a step (``chains`` grasps) at a time, recorded as a chain history."""
    ckpt, done = pipeline.open_run(checkpoint_dir, config, obj)
    if done is not None:
        return done
    # The chains' simulator (same batch size): runs of every method share one in a process.
    sim = as_simulator(obj, backend=backend, trial=trial,
                       batch_size=chains * params.trials_per_proposal)
    gripper = getattr(sim.scene, "gripper", None) or GripperParams()
    steps = params.num_steps
    t0 = time.perf_counter()
    found = antipodal_grasps(obj, steps * chains, seed=seed, gripper=gripper,
                             collides=placement_collisions(sim))
    proposals = found.poses.reshape(steps, chains, 7)
    setup_s = time.perf_counter() - t0
    hist = empty_history(steps, chains)
    t1 = time.perf_counter()
    with tqdm(total=steps, disable=not progress, desc=f"{obj.name} antipodal", unit="step",
              leave=False) as bar:
        for lo in range(0, steps, DEFAULT_CHUNK):
            hi = min(lo + DEFAULT_CHUNK, steps)
            res = sim(proposals[lo:hi].reshape(-1, 7))
            hist["outcomes"][lo:hi] = np.asarray(res.outcome).reshape(hi - lo, chains)
            hist["epsilons"][lo:hi] = _epsilon_as_scored(res).reshape(hi - lo, chains)
            bar.update(hi - lo)
    hist.update(positions=proposals, proposals=proposals, accepted=np.ones((steps, chains), bool))
    demos = pipeline.check_demos(demos) if demos is not None else Demos(
        np.zeros((0, 7), np.float32))
    result = LearnResult(
        object_name=obj.name, object_hash=obj.content_hash, method="antipodal", seed=seed,
        backend=backend, params=params, workflow="active", sketch="none",
        modes_kind="none", **hist, initial_positions=proposals[0],
        modes=np.zeros((0, 7), np.float32), sketch_points=np.zeros((0, 7), np.float32),
        demos=demos,
        info={"setup_seconds": setup_s, "run_seconds": time.perf_counter() - t1,
              "surface_points": found.points, "antipodal_pairs": found.pairs,
              "placement_collisions": found.collisions})
    if ckpt is not None:
        result.save(ckpt.dir)
    return result


def _epsilon_as_scored(res) -> np.ndarray:
    """Epsilon as the grasp density's aux records it: 0 unless the trial made contact
    (success or slipped), was stable and gave a finite value."""
    outcome = np.asarray(res.outcome)
    eps = np.asarray(res.epsilon, np.float32)
    ok = (((outcome == Outcome.SUCCESS) | (outcome == Outcome.SLIPPED))
          & ~np.asarray(res.unstable, bool) & np.isfinite(eps))
    return np.where(ok, np.maximum(eps, 0.0), 0.0).astype(np.float32)
