"""The driver: ``lax.scan`` over steps, ``vmap`` over chains, in jitted chunks.

Keys are derived from the *global* step index (``fold_in(key, t)``, then one split per chain),
so running in chunks, or stopping after ``t`` steps and resuming from the returned state with
``start_step=t``, gives bit-identical results to one uninterrupted call.

The chain axis is the leading axis of every state/info leaf and appears only in
:func:`_init_chains` and :func:`_scan_steps` (``vmap``). With ``devices=`` the same two
functions run inside ``jax.shard_map`` over a ``"chains"`` mesh (:mod:`.sharding`): each device
scans its own block of chains, with the same per-chain keys, so the result is the unsharded one.
"""

from collections.abc import Callable
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from jaxgrasp.mcmc import sharding
from jaxgrasp.mcmc.sharding import CHAINS
from jaxgrasp.types import Array, PRNGKey, SamplingAlgorithm

__all__ = ["sample", "precompile"]


def _is_dynamic(leaf: Any) -> bool:
    return isinstance(leaf, (jax.Array, np.ndarray))


def _partition(tree: Any):
    """Split a pytree into array leaves (traced by jit) and a hashable static remainder."""
    leaves, treedef = jax.tree.flatten(tree)
    dynamic = [leaf if _is_dynamic(leaf) else None for leaf in leaves]
    static = tuple(None if _is_dynamic(leaf) else leaf for leaf in leaves)
    return dynamic, (treedef, static)


def _combine(dynamic, static) -> Any:
    treedef, static_leaves = static
    leaves = [d if s is None else s for d, s in zip(dynamic, static_leaves, strict=True)]
    return jax.tree.unflatten(treedef, leaves)


@partial(jax.jit, static_argnames=("static",))
def _init_chains(dynamic, static, positions: Array):
    alg = _combine(dynamic, static)
    return jax.vmap(alg.init)(positions)


@partial(jax.jit, static_argnames=("static", "num_steps"))
def _scan_steps(dynamic, static, key: PRNGKey, state, start_step: Array, num_steps: int):
    alg = _combine(dynamic, static)
    num_chains = jax.tree.leaves(state)[0].shape[0]

    def one_step(state, t):
        chain_keys = jax.random.split(jax.random.fold_in(key, t), num_chains)
        state, info = jax.vmap(alg.step)(chain_keys, state)
        return state, (state.position, info)

    steps = start_step + jnp.arange(num_steps, dtype=jnp.int32)
    return jax.lax.scan(one_step, state, steps)


@partial(jax.jit, static_argnames=("static", "mesh"))
def _init_chains_sharded(dynamic, static, positions: Array, mesh):
    def local(dynamic, positions):
        return jax.vmap(_combine(dynamic, static).init)(positions)

    return jax.shard_map(local, mesh=mesh, in_specs=(P(), P(CHAINS)), out_specs=P(CHAINS),
                         check_vma=False)(dynamic, positions)


@partial(jax.jit, static_argnames=("static", "num_steps", "mesh", "num_chains"))
def _scan_steps_sharded(dynamic, static, key: PRNGKey, state, start_step: Array,
                        num_steps: int, mesh, num_chains: int):
    """:func:`_scan_steps` with the (padded) chain axis split over ``mesh``; no communication."""

    def local(dynamic, key, state, start_step):
        alg = _combine(dynamic, static)
        block = jax.tree.leaves(state)[0].shape[0]
        # Global chain ids of this block; padding chains reuse the last real chain's key.
        ids = jax.lax.axis_index(CHAINS) * block + jnp.arange(block)
        ids = jnp.minimum(ids, num_chains - 1)

        def one_step(state, t):
            chain_keys = jax.random.split(jax.random.fold_in(key, t), num_chains)[ids]
            state, info = jax.vmap(alg.step)(chain_keys, state)
            return state, (state.position, info)

        steps = start_step + jnp.arange(num_steps, dtype=jnp.int32)
        return jax.lax.scan(one_step, state, steps)

    return jax.shard_map(
        local, mesh=mesh, in_specs=(P(), P(), P(CHAINS), P()),
        out_specs=(P(CHAINS), P(None, CHAINS)), check_vma=False,
    )(dynamic, key, state, start_step)


def _join(*xs):
    # Concrete pieces are joined on the host and put back (no program): jnp.concatenate and
    # jnp.asarray compile one per shape.
    if any(isinstance(x, jax.core.Tracer) for x in xs):
        return jnp.concatenate(xs, axis=0)
    return jax.device_put(np.concatenate([np.asarray(x) for x in xs], axis=0))


def precompile(key: PRNGKey, alg: SamplingAlgorithm, initial_positions, chunk_size: int):
    """Compile what :func:`sample` runs for ``alg`` on chains shaped like
    ``initial_positions`` in chunks of ``chunk_size`` steps (its init and one chunk's scan),
    running nothing: a later unsharded ``sample`` with arrays of the same shapes and dtypes
    finds them compiled. XLA compiles outside the GIL, so a thread can do it while the caller
    prepares those arrays."""
    dynamic, static = _partition(alg)
    positions = jax.ShapeDtypeStruct(np.shape(initial_positions), jnp.float32)
    _init_chains.lower(dynamic, static, positions).compile()
    state = jax.eval_shape(lambda d, p: _init_chains(d, static, p), dynamic, positions)
    step = jax.ShapeDtypeStruct((), jnp.int32)
    _scan_steps.lower(dynamic, static, key, state, step, int(chunk_size)).compile()


def scan_lengths(n: int, chunk_size: int) -> list[int]:
    """The compiled scans that run a chunk of ``n <= chunk_size`` steps: ``[n]`` for a full
    chunk, else the powers of two summing to ``n``, largest first (a run whose length is no
    multiple of ``chunk_size`` ends in scans that every other run shares)."""
    if n == chunk_size:
        return [n]
    return [1 << b for b in range(n.bit_length() - 1, -1, -1) if n >> b & 1]


def sample(
    key: PRNGKey,
    alg: SamplingAlgorithm,
    initial_positions: Array | None,
    num_steps: int,
    *,
    chunk_size: int | None = None,
    callback: Callable | None = None,
    initial_state: Any = None,
    start_step: int = 0,
    return_state: bool = False,
    devices: Any = None,
    keep: bool = True,
):
    """Run ``C`` independent chains of ``alg`` for ``num_steps`` steps.

    Parameters
    ----------
    key : PRNGKey
        Step ``t`` (global index) uses ``fold_in(key, t)``, split into ``C`` chain keys.
    alg : SamplingAlgorithm
        Single-chain ``init``/``step``; vmapped here. Array leaves of ``alg`` (tunables, sketch)
        are jit arguments, so a rebuilt algorithm with new tunables reuses the compiled code.
    initial_positions : (C, d) array, or None when ``initial_state`` is given.
    num_steps : int >= 1
        Steps to run in this call.
    chunk_size : int, optional
        Run in jitted chunks of this many steps (default: one chunk) and call ``callback``
        after each; the result is identical to a single chunk. A shorter last chunk runs as
        scans of powers of two (:func:`scan_lengths`): runs of any length compile at most
        ``log2(chunk_size)`` scans besides the chunk's.
    callback : callable, optional
        ``callback(steps_done, state, positions_chunk, infos_chunk)`` on the host after each
        chunk; ``steps_done`` is the global step count (``start_step`` + steps run so far), the
        value to pass as ``start_step`` when resuming from ``state``.
    initial_state : state pytree with leading axis C, optional
        Resume from this state (e.g. the one returned with ``return_state=True`` or received by
        the callback) instead of calling ``alg.init``.
    start_step : int
        Global index of the first step (for resuming; kernels keep their own step counters in
        the state, this only selects the keys).
    return_state : bool
        Also return the final state.
    devices : None, "all", int, sequence of devices, or Mesh with a "chains" axis
        Shard the chain axis over these devices (:func:`.sharding.chain_mesh`); None runs
        unsharded on the default device. ``C`` is padded to a multiple of the device count
        with copies of the last chain, which never reach the outputs, the state or the
        callback; each chain keeps the key it has unsharded, so the results are identical.
        Multi-process (after :func:`.sharding.initialize_distributed`): pass ``"all"``; every
        process gets the full outputs. Outputs are assembled on the host (no collectives) and
        returned on the default device. Floats may differ from the unsharded run in the last
        bits (XLA compiles the step for the per-device batch; see :mod:`.sharding`).
    keep : bool
        Keep every chunk's positions and infos and return them (default). False: the callback
        is their only consumer (a long run streamed to disk holds one chunk at a time);
        ``positions`` and ``infos`` are returned as None.

    Returns
    -------
    positions : (num_steps, C, d) chain positions after each step (None if not ``keep``).
    infos : the kernel's Info, each leaf with leading axes (num_steps, C) (None if not
        ``keep``).
    state : final state (only with ``return_state=True``).
    """
    if int(num_steps) != num_steps or num_steps < 1:
        raise ValueError(f"num_steps must be a positive integer, got {num_steps}")
    num_steps = int(num_steps)
    if chunk_size is None:
        chunk_size = num_steps
    if int(chunk_size) != chunk_size or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size}")
    if start_step < 0:
        raise ValueError(f"start_step must be non-negative, got {start_step}")
    if not keep and callback is None:
        raise ValueError("keep=False discards every step: give a callback to receive them")
    mesh = sharding.chain_mesh(devices)
    if mesh is not None and any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(
            (key, initial_positions, initial_state))):
        raise ValueError("devices= shards a top-level run; call sample() outside jit/vmap")
    dynamic, static = _partition(alg)
    if mesh is not None:  # the algorithm's arrays, replicated on every device
        dynamic_on_mesh = sharding.put(dynamic, mesh, P())

    if initial_state is None:
        if initial_positions is None:
            raise ValueError("give initial_positions (C, d) or initial_state")
        positions0 = (
            np.asarray(initial_positions)
            if not isinstance(initial_positions, jax.core.Tracer)
            else initial_positions
        )
        if np.ndim(positions0) != 2:
            raise ValueError(
                f"initial_positions must have shape (C, d), got {np.shape(positions0)}"
            )
        if isinstance(positions0, np.ndarray) and not np.all(np.isfinite(positions0)):
            raise ValueError("initial_positions contains non-finite values")
        num_chains = np.shape(positions0)[0]
        if mesh is None:
            state = _init_chains(dynamic, static, jnp.asarray(initial_positions))
        else:
            padded = sharding.pad_chains(
                jnp.asarray(initial_positions), sharding.padded_size(num_chains, mesh))
            state = _init_chains_sharded(
                dynamic_on_mesh, static, sharding.put(padded, mesh, P(CHAINS)), mesh)
    else:
        num_chains = jax.tree.leaves(initial_state)[0].shape[0]
        state = initial_state
        if mesh is not None:
            padded = sharding.pad_chains(
                initial_state, sharding.padded_size(num_chains, mesh))
            state = sharding.put(padded, mesh, P(CHAINS))

    if mesh is None:
        def run(state, step, n):
            return _scan_steps(dynamic, static, key, state, step, n)

        def real(tree, axis):  # the chains the caller asked for
            return tree
    else:
        key_on_mesh = sharding.put(key, mesh, P())

        def run(state, step, n):
            step = sharding.put(step, mesh, P())
            return _scan_steps_sharded(
                dynamic_on_mesh, static, key_on_mesh, state, step, n, mesh, num_chains)

        def real(tree, axis):
            return sharding.gather(tree, num_chains, axis)

    pos_chunks, info_chunks = [], []
    done = 0
    while done < num_steps:
        parts = []
        for n in scan_lengths(min(int(chunk_size), num_steps - done), int(chunk_size)):
            state, out = run(state, jnp.asarray(start_step + done, jnp.int32), n)
            done += n
            parts.append(real(out, 1))
        pos, infos = parts[0] if len(parts) == 1 else jax.tree.map(_join, *parts)
        if keep:
            pos_chunks.append(pos)
            info_chunks.append(infos)
        if callback is not None:
            callback(start_step + done, real(state, 0), pos, infos)

    if not keep:
        positions = infos = None
    elif len(pos_chunks) == 1:
        positions, infos = pos_chunks[0], info_chunks[0]
    else:
        positions = jnp.concatenate(pos_chunks, axis=0)
        infos = jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=0), *info_chunks)
    if return_state:
        return positions, infos, real(state, 0)
    return positions, infos
