"""Running the chains of a learning run: every proposal's outcome recorded, checkpointed.

Every proposal is one physics trial and is counted (success / slipped / collision / miss),
burn-in included, as in the paper's tables. The outcome of a proposal is read from the
density's aux in the step info: it is never simulated twice.
"""

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxgrasp import mcmc
from jaxgrasp.learn.files.checkpoint import CheckpointDir, state_from_arrays, state_to_arrays
from jaxgrasp.learn.metric import GraspMetric

__all__ = ["run_chains", "save_checkpoint", "empty_history", "DEFAULT_CHUNK", "HISTORY"]

#: Steps per jitted chunk (progress and checkpoint granularity); one size for every phase so
#: the sketch run, the main run and resumed runs share one compiled scan.
DEFAULT_CHUNK = 10
HISTORY = ("positions", "proposals", "outcomes", "epsilons", "accepted", "is_jump")


def empty_history(num_steps: int, chains: int) -> dict:
    """Preallocated host arrays for a run's history (filled chunk by chunk)."""
    return {
        "positions": np.zeros((num_steps, chains, 7), np.float32),
        "proposals": np.zeros((num_steps, chains, 7), np.float32),
        "outcomes": np.full((num_steps, chains), -1, np.int8),
        "epsilons": np.zeros((num_steps, chains), np.float32),
        "accepted": np.zeros((num_steps, chains), bool),
        "is_jump": np.zeros((num_steps, chains), bool),
    }


def _store_chunk(hist: dict, lo: int, positions, infos, metric: GraspMetric) -> int:
    """Copy one chunk of sampler output into the history at rows ``lo:`` (in grasp
    coordinates); returns the end row."""
    is_jump = getattr(infos, "is_jump", None)
    # One transfer to the host for the whole chunk.
    positions, proposals, outcomes, epsilons, accepted, is_jump = jax.device_get(
        (positions, infos.proposal, infos.aux["outcome"], infos.aux["epsilon"],
         infos.is_accepted, is_jump))
    hi = lo + positions.shape[0]
    hist["positions"][lo:hi] = metric.to_grasp(positions)
    hist["proposals"][lo:hi] = metric.to_grasp(proposals)
    hist["outcomes"][lo:hi] = outcomes
    hist["epsilons"][lo:hi] = epsilons
    hist["accepted"][lo:hi] = accepted
    hist["is_jump"][lo:hi] = False if is_jump is None else is_jump
    return hi


def _resume(checkpoint: CheckpointDir, hist: dict, alg, init):
    """``(step, state or None)`` of the checkpoint; its history copied into ``hist``."""
    start, arrays = checkpoint.load_state()
    if arrays is None:
        return start, None
    for name in HISTORY:
        if arrays[name].shape != hist[name].shape:
            raise ValueError(f"checkpoint history {name!r} has shape "
                             f"{arrays[name].shape}, expected {hist[name].shape}")
        hist[name][...] = arrays[name]
    template = jax.eval_shape(jax.vmap(alg.init), init)
    return start, state_from_arrays(arrays, template)


def run_chains(alg, key, initial_positions, num_steps: int, *, checkpoint: CheckpointDir = None,
               checkpoint_every: int | None = None, progress: bool = True, desc: str = "",
               devices=None, metric: GraspMetric | None = None):
    """Run ``alg`` on C chains for ``num_steps`` steps, recording every proposal's outcome.

    With ``checkpoint``, the sampler state and the history so far are saved every
    ``checkpoint_every`` steps, and a run finding a checkpoint continues from it; the result
    is bit-identical to an uninterrupted run (per-step keys depend on the global step only).
    ``metric``: the sampler's coordinates (:func:`jaxgrasp.learn.algorithm.sampler_metric`);
    the initial positions and the returned history are grasps.

    Returns
    -------
    dict of numpy arrays: positions (S, C, 7), proposals (S, C, 7), outcomes (S, C) int8,
    epsilons (S, C), accepted (S, C), is_jump (S, C).
    """
    metric = GraspMetric() if metric is None else metric
    init = metric.to_sampler(initial_positions)
    hist = empty_history(num_steps, init.shape[0])
    start, state = (0, None) if checkpoint is None else _resume(checkpoint, hist, alg, init)
    if start >= num_steps:
        return hist
    every = checkpoint_every if checkpoint_every is not None else DEFAULT_CHUNK
    cursor = [start]
    bar = tqdm(total=num_steps, initial=start, disable=not progress, desc=desc, unit="step",
               leave=False)

    def on_chunk(steps_done, chain_state, positions, infos):
        cursor[0] = _store_chunk(hist, cursor[0], positions, infos, metric)
        if cursor[0] != steps_done:
            raise RuntimeError(f"sampler reported {steps_done} steps, history holds {cursor[0]}")
        bar.update(positions.shape[0])
        if checkpoint is not None:
            save_checkpoint(checkpoint, steps_done, hist, chain_state)

    try:
        mcmc.sample(key, alg, init if state is None else None, num_steps - start,
                    chunk_size=every, callback=on_chunk, initial_state=state, start_step=start,
                    devices=devices, keep=False)  # the history holds the steps
    except Exception as err:
        # Ctrl-C inside the physics callback reaches us wrapped in an XLA runtime error.
        if "KeyboardInterrupt" in str(err):
            raise KeyboardInterrupt(f"interrupted; last checkpoint kept: {err}") from None
        raise
    finally:
        bar.close()
    return hist


def save_checkpoint(checkpoint: CheckpointDir, step: int, hist: dict, state) -> None:
    """Write the sampler state after ``step`` steps and the history so far (atomically)."""
    checkpoint.save_state(step, {**hist, **state_to_arrays(state)})
