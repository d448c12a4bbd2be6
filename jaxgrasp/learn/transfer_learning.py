"""Transfer learning of grasps to a novel, similar object (paper §5, experiments 4-5).

No new rough sketch is made: the chain history of the known (source) object is Kameleon's
sketch, thinned evenly to ``params.sketch_size`` points. The GDMC modes are either the
source's demonstrated grasps (``modes="source"``, experiment 4: no knowledge of the target)
or demonstrations made on the target itself (``modes="target"``, experiment 5). Objects share
one canonical frame (standing on z = 0, revolution axis z, handle along +x), so source poses
are used on the target unchanged, as in the paper; with ``size_aware=True`` the sketch and the
source modes are first moved with the two objects' sizes (:class:`~jaxgrasp.learn.setup.resize.
SizeMap`).
"""

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from jaxgrasp import objects
from jaxgrasp.learn import pipeline
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.files.results import load as load_result
from jaxgrasp.learn.inputs import (
    check_chains,
    check_every,
    check_seed,
    resolve_object,
    resolve_params,
)
from jaxgrasp.learn.setup.demos import Demos, demonstrations
from jaxgrasp.learn.setup.resize import SizeMap
from jaxgrasp.learn.sim import run_backend

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
             demos=None, size_aware=False) -> LearnResult:
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
    size_aware : bool or SizeMap
        Move the source's chain history (the sketch) and, with ``modes="source"``, its demos
        into the target's frame before sampling: True maps with the two objects' rim radius
        and height (:meth:`SizeMap.between`; the source is looked up by its name among the
        shipped objects), a :class:`~jaxgrasp.learn.setup.resize.SizeMap` is used as given. False:
        the paper's transfer.

    Returns
    -------
    LearnResult with ``workflow="transfer"``, ``sketch="source"``, ``modes_kind=modes``.
    """
    backend = run_backend(backend, trial)
    if not isinstance(size_aware, bool | SizeMap):
        raise ValueError(f"size_aware must be a bool or a SizeMap, got {size_aware!r}")
    if modes not in MODES:
        raise ValueError(f"unknown modes {modes!r}; expected one of {MODES}")
    if isinstance(source_result, str | Path):
        source_result = load_result(source_result)
    if not isinstance(source_result, LearnResult):
        raise ValueError(f"source_result must be a LearnResult or a result directory, got "
                         f"{type(source_result).__name__}")
    source = source_result
    params = resolve_params(params if params is not None else source.params,
                            iterations=iterations, burn_in=burn_in)
    chains = check_chains(source.num_chains if chains is None else chains)
    seed = check_seed(seed)
    check_every(checkpoint_every)
    target = resolve_object(target_obj)
    if demos is not None:
        if modes != "target":
            raise ValueError("demos= is only used with modes='target' (modes='source' uses "
                             "the source result's demonstrations)")
        demos = pipeline.check_demos(demos)
    if modes == "source" and len(source.demos.poses) == 0:
        raise ValueError("the source result holds no demonstrated grasps to use as modes")
    source_id = hashlib.sha256(np.ascontiguousarray(source.positions).tobytes()).hexdigest()
    config = {"workflow": "transfer", "object": target.name, "object_hash": target.content_hash,
              "method": "kameleon_darting", "sketch": "source", "modes": modes,
              "source_object": source.object_name, "source_hash": source.object_hash,
              "source_history_sha256": source_id, "chains": chains, "seed": seed,
              "backend": backend, "params": params.to_dict()}
    size_map = size_aware if isinstance(size_aware, SizeMap) else None
    if size_aware is True:
        if source.object_name not in objects.names():
            raise ValueError(f"size_aware=True looks the source object up among the shipped "
                             f"objects, and {source.object_name!r} is not one; pass "
                             f"size_aware=jg.learn.SizeMap.between(source_obj, target_obj)")
        size_map = SizeMap.between(objects.load(source.object_name), target)
    if size_map is not None:  # only then in the config: older checkpoints still resume
        config["size_map"] = dataclasses.asdict(size_map)

    def make_setup(sim, checkpoint):
        run_demos = demos
        if modes == "source":
            run_demos = (source.demos if size_map is None
                         else Demos(size_map(source.demos.poses)))
        elif run_demos is None:
            run_demos = demonstrations(target, num=params.num_demos, seed=seed, trial=sim,
                                       params=params, progress=progress,
                                       checkpoint=checkpoint)
        sketch = history_sketch(source, params.sketch_size)
        return run_demos, (sketch if size_map is None else size_map(sketch))

    kind = "source" if size_map is None else "source_resized"
    record = {"workflow": "transfer", "sketch": kind,
              "modes_kind": kind if modes == "source" else modes,
              "source_object": source.object_name}
    info = {"source_hash": source.object_hash, "source_history_sha256": source_id}
    return pipeline.run(
        target, config, make_setup, method="kameleon_darting", chains=chains, seed=seed,
        stream=3, params=params, backend=backend, record=record, info=info, trial=trial,
        devices=devices, checkpoint_dir=checkpoint_dir, checkpoint_every=checkpoint_every,
        progress=progress, desc=f"{source.object_name} -> {target.name} ({modes} modes)")
