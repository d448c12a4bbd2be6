"""Transfer learning of grasps to a novel, similar object (paper §5, experiments 4-5).

No new rough sketch is made: the chain history of the known (source) object is Kameleon's
sketch, thinned evenly to ``params.sketch_size`` points. The GDMC modes are either the
source's demonstrated grasps (``modes="source"``, experiment 4: no knowledge of the target)
or demonstrations made on the target itself (``modes="target"``, experiment 5). Objects share
one canonical frame (standing on z = 0, revolution axis z, handle along +x), so source poses
are used on the target unchanged.
"""

import hashlib
import time
from pathlib import Path

import jax
import numpy as np

from jaxgrasp.learn import active_learning as _active
from jaxgrasp.learn.demos import demonstrations
from jaxgrasp.learn.results import (
    Demos,
    LearnResult,
    demo_result_arrays,
    demo_results_from_arrays,
)
from jaxgrasp.learn.results import load as load_result
from jaxgrasp.learn.sim import as_simulator, run_backend

__all__ = ["transfer", "MODES", "history_sketch"]

MODES = ("source", "target")


def history_sketch(source: LearnResult, size: int) -> np.ndarray:
    """The source chain history (all steps and chains) thinned evenly to at most ``size``."""
    history = np.asarray(source.positions, np.float32).reshape(-1, 7)
    if len(history) <= size:
        return history
    idx = np.linspace(0, len(history) - 1, size).round().astype(np.int64)
    return history[idx]


def transfer(source_result, target_obj, *, modes="source", chains=None, iterations=None,
             burn_in=None, seed=0, params=None, backend="auto", checkpoint_dir=None,
             checkpoint_every=None, progress=True, trial=None, devices=None,
             demos=None) -> LearnResult:
    """Kameleon + GDMC on ``target_obj``, initialized from a learned ``source_result``.

    Parameters
    ----------
    source_result : LearnResult or path
        A result of :func:`jaxgrasp.learn.active` (or a directory it was saved to).
    target_obj : GraspObject, Scene or str
        The novel object.
    modes : {"source", "target"}
        GDMC modes: the source's demonstrated grasps, or new demos on the target.
    chains : int, optional
        Default: as many as the source run.
    iterations, burn_in : int, optional
        Overrides of ``params`` (default: the source's parameters).
    seed : int
    params : LearnParams, optional
        Default: the source's parameters.
    backend, checkpoint_dir, checkpoint_every, progress, trial, devices
        As in :func:`jaxgrasp.learn.active`.
    demos : Demos, optional
        ``modes="target"``: precomputed demonstrations on the target (as
        ``jg.learn.demonstrations(target, num=params.num_demos, seed=seed, params=params)``);
        computed when None. ValueError with ``modes="source"`` (the source's demos are used).

    Returns
    -------
    LearnResult with ``workflow="transfer"``, ``sketch="source"``, ``modes_kind=modes``.
    """
    backend = run_backend(backend, trial)
    if modes not in MODES:
        raise ValueError(f"unknown modes {modes!r}; expected one of {MODES}")
    if isinstance(source_result, str | Path):
        source_result = load_result(source_result)
    if not isinstance(source_result, LearnResult):
        raise ValueError(f"source_result must be a LearnResult or a result directory, got "
                         f"{type(source_result).__name__}")
    source = source_result
    params = _active.resolve_params(params if params is not None else source.params,
                                    iterations=iterations, burn_in=burn_in)
    chains = _active.check_chains(source.num_chains if chains is None else chains)
    seed = _active.check_seed(seed)
    _active._check_every(checkpoint_every)
    target = _active.resolve_object(target_obj)
    if demos is not None:
        if modes != "target":
            raise ValueError("demos= is only used with modes='target' (modes='source' uses "
                             "the source result's demonstrations)")
        demos = _active.check_demos(demos)
    if modes == "source" and len(source.demos.poses) == 0:
        raise ValueError("the source result holds no demonstrated grasps to use as modes")
    source_id = hashlib.sha256(np.ascontiguousarray(source.positions).tobytes()).hexdigest()
    config = {"workflow": "transfer", "object": target.name, "object_hash": target.content_hash,
              "method": "kameleon_darting", "sketch": "source", "modes": modes,
              "source_object": source.object_name, "source_hash": source.object_hash,
              "source_history_sha256": source_id, "chains": chains, "seed": seed,
              "backend": backend, "params": params.to_dict()}
    ckpt, done = _active.open_run(checkpoint_dir, config, target)
    if done is not None:
        return done
    sim = as_simulator(target, backend=backend, trial=trial,
                       batch_size=_active.simulator_batch(chains, devices))
    t0 = time.perf_counter()
    setup = ckpt.load_setup() if ckpt is not None else None
    if setup is None:
        if modes == "source":
            demos = source.demos
        elif demos is None:
            demos = demonstrations(target, num=params.num_demos, seed=seed, trial=sim,
                                   params=params)
        setup = {"demo_poses": np.asarray(demos.poses),
                 "sketch_points": history_sketch(source, params.sketch_size),
                 **demo_result_arrays(demos.results)}
        if ckpt is not None:
            ckpt.save_setup(setup)
    demos = Demos(setup["demo_poses"], demo_results_from_arrays(setup))
    modes_arr = np.asarray(demos.poses, np.float32)
    init = modes_arr[np.arange(chains) % len(modes_arr)]
    setup_s = time.perf_counter() - t0
    alg = _active.make_algorithm("kameleon_darting", sim, params,
                                 sketch=setup["sketch_points"], modes=modes_arr,
                                 traced=devices is not None and _active.is_traceable(sim))
    t1 = time.perf_counter()
    hist = _active.run_chains(
        alg, jax.random.fold_in(jax.random.key(seed), 3), init, params.num_steps,
        checkpoint=ckpt, checkpoint_every=checkpoint_every, progress=progress,
        desc=f"{source.object_name} -> {target.name} ({modes} modes)", devices=devices,
        metric=_active.sampler_metric("kameleon_darting", params))
    result = LearnResult(
        object_name=target.name, object_hash=target.content_hash, workflow="transfer",
        method="kameleon_darting", sketch="source", modes_kind=modes, seed=seed,
        backend=backend, params=params, **hist, initial_positions=init, modes=modes_arr,
        sketch_points=setup["sketch_points"], demos=demos, source_object=source.object_name,
        info={"source_hash": source.object_hash, "source_history_sha256": source_id,
              "setup_seconds": setup_s, "run_seconds": time.perf_counter() - t1},
    )
    if ckpt is not None:
        result.save(ckpt.dir)
    return result
