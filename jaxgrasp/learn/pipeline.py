"""One learning run, whatever the workflow: checkpoint, setup, sampler, chains, result.

A workflow (:func:`jaxgrasp.learn.active`, :func:`jaxgrasp.learn.transfer`) checks its
arguments, describes the run (its checkpoint ``config`` and the result's record) and supplies
its setup: the demonstrated grasps (the GDMC modes and chain starts) and Kameleon's sketch.
:func:`run` does the rest, the same way for every workflow:

1. a checkpoint directory with a finished result returns it; one with a saved setup reuses it;
2. the setup is made (and saved) on the object's :class:`~jaxgrasp.learn.sim.Simulator`;
3. chain ``c`` starts at demo ``c mod m``; the sampler runs ``burn_in + iterations`` steps,
   checkpointed (:func:`jaxgrasp.learn.chains.run_chains`);
4. the :class:`~jaxgrasp.learn.files.results.LearnResult` is assembled (and saved).
"""

import threading
import time
import warnings

import jax
import numpy as np

from jaxgrasp.learn.algorithm import make_algorithm, object_symmetry, sampler_metric
from jaxgrasp.learn.chains import DEFAULT_CHUNK, run_chains
from jaxgrasp.learn.files.checkpoint import CheckpointDir
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.files.results import load as load_result
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.setup.demos import Demos, demo_result_arrays, demo_results_from_arrays
from jaxgrasp.learn.sim import as_simulator
from jaxgrasp.mcmc import sharding
from jaxgrasp.mcmc.sample import precompile

__all__ = ["run", "check_demos", "chain_starts", "open_run", "simulator_batch"]


def check_demos(demos) -> Demos:
    """Validate precomputed demonstrations (a ``Demos`` with at least one (m, 7) pose)."""
    if not isinstance(demos, Demos):
        raise ValueError(f"demos must be a jg.learn.Demos, got {type(demos).__name__}")
    poses = np.asarray(demos.poses, np.float32)
    if poses.ndim != 2 or poses.shape[1] != 7 or len(poses) == 0:
        raise ValueError(f"demos.poses must be a non-empty (m, 7) array, got {poses.shape}")
    return Demos(poses, demos.results, demos.spares)


def open_run(checkpoint_dir, config: dict, obj):
    """``(checkpoint dir or None, finished result or None)`` for a run with ``config``."""
    if checkpoint_dir is None:
        return None, None
    ckpt = CheckpointDir(checkpoint_dir, config)
    return ckpt, (load_result(ckpt.dir, obj) if ckpt.has_result() else None)


def chain_starts(demos: Demos, chains: int, *, spread: bool) -> np.ndarray:
    """Chain ``c`` at demo ``c`` for ``c < m``; with ``spread`` the next chains at the search's
    spare successes, one each; the rest cycle (chain ``c`` at start ``c mod`` their number)."""
    modes = np.asarray(demos.poses, np.float32)
    spares = demos.spares[: max(chains - len(modes), 0)] if spread else modes[:0]
    starts = np.concatenate([modes, np.asarray(spares, np.float32)])
    return starts[np.arange(chains) % len(starts)]


def simulator_batch(chains: int, devices) -> int:
    """The Simulator batch size: all chains, or the chains of one device when sharded."""
    if devices is None:
        return chains
    mesh = sharding.chain_mesh(devices)
    return sharding.padded_size(chains, mesh) // mesh.shape[sharding.CHAINS]


def run(obj, config: dict, make_setup, *, method: str, chains: int, seed: int, stream: int,
        params: LearnParams, backend: str, record: dict, info: dict | None = None,
        trial=None, devices=None, checkpoint_dir=None, checkpoint_every=None,
        progress=True, desc="") -> LearnResult:
    """Run one learning workflow on ``obj`` (a GraspObject; arguments already checked).

    Parameters
    ----------
    config : dict
        The run's identity in its checkpoint directory (another config is refused).
    make_setup : callable ``(sim, checkpoint) -> (Demos, sketch (n, 7))``
        ``checkpoint`` is the run's CheckpointDir (or None): the demo search saves its
        simulated batches there as they finish.
        The workflow's setup, called when no saved setup exists.
    method : str
        :func:`jaxgrasp.learn.algorithm.make_algorithm` method.
    chains, seed : int
    stream : int
        The chains' key is ``fold_in(key(seed), stream)`` (one stream per workflow).
    params : LearnParams
    backend : str
        The resolved backend name the result records.
    record : dict
        The result's workflow, sketch, modes_kind (and source_object) fields.
    info : dict, optional
        Extra entries of the result's info (timings are added).
    trial, devices, checkpoint_dir, checkpoint_every, progress
        As in :func:`jaxgrasp.learn.active`.
    desc : str
        Progress bar label.
    """
    ckpt, done = open_run(checkpoint_dir, config, obj)
    if done is not None:
        return done
    # One step simulates every chain's proposal and its perturbed tries in one batch.
    sim = as_simulator(obj, backend=backend, trial=trial,
                       batch_size=simulator_batch(chains, devices) * params.trials_per_proposal)
    t0 = time.perf_counter()
    setup = ckpt.load_setup() if ckpt is not None else None
    if setup is None:
        ahead = None
        if devices is None and method in ("kameleon_darting", "random_walk"):
            ahead = threading.Thread(target=_compile_ahead, daemon=True, args=(
                obj, method, sim, params, chains, jax.random.fold_in(jax.random.key(seed),
                                                                       stream),
                checkpoint_every or DEFAULT_CHUNK))
            ahead.start()
        demos, sketch_points = make_setup(sim, ckpt)
        if ahead is not None:
            ahead.join()
        setup = {"demo_poses": np.asarray(demos.poses), "sketch_points": sketch_points,
                 "demo_spares": np.asarray(demos.spares), **demo_result_arrays(demos.results)}
        if ckpt is not None:
            ckpt.save_setup(setup)
    demos = Demos(setup["demo_poses"], demo_results_from_arrays(setup),
                  setup.get("demo_spares"))
    modes = np.asarray(demos.poses, np.float32)
    init = chain_starts(demos, chains, spread=params.spread_starts)
    setup_s = time.perf_counter() - t0
    info = dict(info or {})
    symmetry = _symmetry(obj, method, params)
    if symmetry is not None:
        info["symmetry"] = symmetry.to_dict()
    alg = make_algorithm(method, sim, params, sketch=setup["sketch_points"], modes=modes,
                         traced=devices is not None and sim.traceable, symmetry=symmetry)
    t1 = time.perf_counter()
    hist = run_chains(alg, jax.random.fold_in(jax.random.key(seed), stream), init,
                      params.num_steps, checkpoint=ckpt, checkpoint_every=checkpoint_every,
                      devices=devices, progress=progress, metric=sampler_metric(method, params),
                      desc=desc)
    result = LearnResult(
        object_name=obj.name, object_hash=obj.content_hash, method=method, seed=seed,
        backend=backend, params=params, **record, **hist, initial_positions=init, modes=modes,
        sketch_points=setup["sketch_points"], demos=demos,
        info={**info, "setup_seconds": setup_s,
              "run_seconds": time.perf_counter() - t1},
    )
    if ckpt is not None:
        result.save(ckpt.dir)
    return result


def _symmetry(obj, method, params):
    """The symmetry the run's moves follow (Kameleon + GDMC with axis moves), else None."""
    if method == "kameleon_darting" and params.axis_moves > 0:
        return object_symmetry(obj, params.symmetry)
    return None


def _compile_ahead(obj, method, sim, params, chains, key, chunk_size) -> None:
    """Compile the run's sampler while its demos and sketch are made (a thread: XLA compiles
    outside the GIL), on placeholder arrays of their shapes: the first step then waits for no
    compile. A run whose arrays differ (fewer demos found) compiles its own, as without."""
    try:
        rng = np.random.default_rng(0)
        modes = np.concatenate([0.01 * rng.normal(size=(params.num_demos, 3)),
                                rng.normal(size=(params.num_demos, 4))], axis=1)
        modes[:, 3:] /= np.linalg.norm(modes[:, 3:], axis=1, keepdims=True)
        modes = modes.astype(np.float32)
        size = params.sketch_size if method == "kameleon_darting" else 0
        sketch = np.resize(modes, (size, 7)) + 1e-3 * rng.normal(size=(size, 7))
        alg = make_algorithm(method, sim, params, sketch=sketch.astype(np.float32),
                             modes=modes, symmetry=_symmetry(obj, method, params))
        init = sampler_metric(method, params).to_sampler(modes[np.arange(chains) % len(modes)])
        precompile(key, alg, init, chunk_size)
    except Exception as err:  # only time is lost: the run compiles what it needs itself
        warnings.warn(f"compiling the sampler ahead failed ({err!r}); the run compiles it",
                      RuntimeWarning, stacklevel=1)
