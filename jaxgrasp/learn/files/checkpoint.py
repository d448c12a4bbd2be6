"""Checkpoint and resume of a learning run.

A checkpoint directory holds, each written atomically (temp file + ``os.replace``):

- ``setup.npz``: the run's configuration and the inputs made before sampling (demos,
  sketch); written once.
- ``checkpoint.npz``: the sampler state after ``step`` steps (the pytree's leaves) and the
  history arrays filled so far; rewritten every ``checkpoint_every`` steps.
- ``result.npz/.json``: the finished run (then a new call just loads it).

Resuming runs ``jg.mcmc.sample`` from the saved state with ``start_step=step``; per-step keys
are ``fold_in(key, global_step)``, so the resumed run is bit-identical to an uninterrupted one.
"""

import json
from pathlib import Path

import jax
import numpy as np

from jaxgrasp.learn.files.atomic import atomic_write_bytes, jsonable, npz_bytes, read_npz

__all__ = ["CheckpointDir", "CheckpointMismatch", "state_to_arrays", "state_from_arrays"]


class CheckpointMismatch(ValueError):
    """A checkpoint directory written for another run configuration."""


def state_to_arrays(state, prefix="state_") -> dict:
    """Flatten a sampler state pytree into ``{prefix000: array, ...}`` (typed keys as data)."""
    leaves = [jax.random.key_data(leaf) if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key)
              else leaf for leaf in jax.tree.leaves(state)]
    # One transfer to the host for the whole state.
    return {f"{prefix}{i:03d}": np.asarray(leaf)
            for i, leaf in enumerate(jax.device_get(leaves))}


def state_from_arrays(arrays: dict, template, prefix="state_"):
    """Rebuild a state pytree from :func:`state_to_arrays` output, checked against ``template``.

    ``template`` is a pytree of arrays or ShapeDtypeStructs with the expected structure (e.g.
    ``jax.eval_shape`` of the vmapped ``init``). Raises ValueError on any mismatch.
    """
    leaves, treedef = jax.tree.flatten(template)
    keys = sorted(k for k in arrays if k.startswith(prefix))
    if len(keys) != len(leaves):
        raise ValueError(f"checkpoint holds {len(keys)} state arrays, the sampler's state has "
                         f"{len(leaves)}: the checkpoint was written by another sampler")
    restored = []
    for key, like in zip(keys, leaves, strict=True):
        value = arrays[key]
        if jax.dtypes.issubdtype(like.dtype, jax.dtypes.prng_key):
            impl = jax.random.key_impl(like) if isinstance(like, jax.Array) else None
            value = jax.random.wrap_key_data(value, impl=impl)
        elif value.dtype != like.dtype:
            raise ValueError(f"checkpoint state {key} has dtype {value.dtype}, expected "
                             f"{like.dtype}")
        if tuple(value.shape) != tuple(like.shape):
            raise ValueError(f"checkpoint state {key} has shape {value.shape}, expected "
                             f"{tuple(like.shape)} (different number of chains or dimensions)")
        restored.append(jax.numpy.asarray(value))
    return jax.tree.unflatten(treedef, restored)


#: File prefix of the setup's parts (removed once the whole setup is saved).
PART_PREFIX = "setup_part_"


class CheckpointDir:
    """The files of one resumable run, tied to its configuration.

    ``setup.npz`` and ``checkpoint.npz`` are single files (their metadata is a JSON string
    inside the archive), so each is replaced in one atomic step and can never be torn.

    Parameters
    ----------
    directory : path
    config : dict
        JSON-able description of the run (object + hash, method, params, seed, chains, ...).
        A directory written for another configuration is refused with a ValueError.
    """

    def __init__(self, directory, config: dict):
        self.dir = Path(directory)
        self.config = _normalize(config)
        if (self.dir / "setup.npz").exists():
            _, meta = self._read("setup")
            self._check(meta, "setup.npz")

    def _read(self, stem):
        path = self.dir / f"{stem}.npz"
        arrays = read_npz(path, f"checkpoint file {path}")
        try:
            meta = json.loads(str(arrays.pop("meta_json")))
            if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
                raise ValueError("no 'config' record")
            if stem == "checkpoint" and (not isinstance(meta.get("step"), int)
                                         or meta["step"] < 0):
                raise ValueError(f"bad step {meta.get('step')!r}")
        except (KeyError, ValueError) as err:
            raise ValueError(f"{path} is not a jaxgrasp checkpoint (metadata: {err}); delete "
                             "it or use a fresh checkpoint directory") from None
        return arrays, meta

    def _write(self, stem, arrays, meta):
        payload = {**arrays, "meta_json": np.str_(json.dumps(jsonable(meta), sort_keys=True))}
        atomic_write_bytes(self.dir / f"{stem}.npz", npz_bytes(payload))

    def _check(self, meta, name):
        if meta.get("config") != self.config:
            diff = _diff(meta.get("config", {}), self.config)
            raise CheckpointMismatch(
                f"checkpoint directory {str(self.dir)!r} belongs to another run ({name} differs "
                f"in {diff}); use a fresh directory or the same arguments")

    # -- finished result --

    def has_result(self) -> bool:
        return (self.dir / "result.json").exists()

    # -- setup --

    def load_setup(self):
        if not (self.dir / "setup.npz").exists():
            return None
        arrays, meta = self._read("setup")
        self._check(meta, "setup.npz")
        return arrays

    def save_setup(self, arrays: dict) -> None:
        self._write("setup", arrays, {"config": self.config})
        for part in self.dir.glob(f"{PART_PREFIX}*.npz"):  # the setup holds what they made
            part.unlink(missing_ok=True)

    # -- parts of the setup, saved as they finish (the demo search's batches) --

    def load_part(self, name: str):
        """The arrays saved as ``name`` for this run, or None."""
        stem = PART_PREFIX + name
        if not (self.dir / f"{stem}.npz").exists():
            return None
        arrays, meta = self._read(stem)
        self._check(meta, f"{stem}.npz")
        return arrays

    def save_part(self, name: str, arrays: dict) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        self._write(PART_PREFIX + name, arrays, {"config": self.config})

    # -- sampler state --

    def load_state(self):
        """``(step, arrays)`` of the last checkpoint, or ``(0, None)``."""
        if not (self.dir / "checkpoint.npz").exists():
            return 0, None
        arrays, meta = self._read("checkpoint")
        self._check(meta, "checkpoint.npz")
        return int(meta["step"]), arrays

    def save_state(self, step: int, arrays: dict) -> None:
        self._write("checkpoint", arrays, {"config": self.config, "step": int(step)})


def _normalize(config: dict) -> dict:
    """Round-trip through JSON so tuples/numpy scalars compare equal to what was stored."""
    return json.loads(json.dumps(jsonable(config), sort_keys=True))


def _diff(a: dict, b: dict) -> list:
    keys = sorted(set(a) | set(b))
    return [k for k in keys if a.get(k) != b.get(k)]
