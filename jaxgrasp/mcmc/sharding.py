"""Chains across devices and hosts: a 1-D ``"chains"`` mesh, padding, gathering.

Chains are independent, so sharding them needs no communication inside a step: each device
runs the vmapped kernel (and, when the physics is traced into the target, the batched MJX
rollout) on its own block of chains. :func:`jaxgrasp.mcmc.sample` does this with
``jax.shard_map`` when given ``devices=``; this module holds the pieces it uses.

Multi-host (one process per host, e.g. one per GPU node): call :func:`initialize_distributed`
first thing in the script, on every host, with the same arguments and the same seed; then
``jg.mcmc.sample(..., devices="all")`` spans every device of every process. Process ``p``
owns a contiguous block of chains. Outputs are gathered so every process receives the full
``C`` chains (:func:`gather`); write files only where :func:`is_main_process` is true.

Reproducibility: chain ``i`` uses the same keys and starts from the same state whatever the
device count (padding chains copy the last chain and its key): it is the unsharded chain, up
to float rounding. Float results may differ in the last bits, because each device runs the step
compiled for its block of ``C / devices`` chains and XLA's code for reductions and small
matrix products depends on the batch size (an unsharded run with another number of chains
shows the same 1-ulp effect); over many steps such a difference can, rarely, flip an
accept/reject decision and the chains then part. Resuming on the same device count is
bit-identical.

Forced CPU devices (``--xla_force_host_platform_device_count``, for tests and the scaling
benchmark) are threads of one process sharing one intra-op thread pool of ~#cores workers.
jaxlib's batched LAPACK kernels (the QR in Kameleon's proposal) split a large batch over that
same pool and wait for it; when every worker is such a device waiting, the run deadlocks.
Real accelerators and one CPU device per process are not affected.

Physics reached through a host callback (``jax.pure_callback``, as the learning workflows'
``Simulator`` does) is *not* moved onto the devices by sharding: inside ``shard_map`` the
callback runs once per device shard, on the host that owns the shard, with that shard's
chains; the MuJoCo C backend then uses that host's CPU threads. Only a target traced with
the MJX trial runs its rollouts on the devices. A callback's inner jitted computation runs
on the host's default device, so on a multi-GPU host every shard's rollouts would land on
one GPU: ``jg.learn.active(..., devices=...)`` therefore traces a traceable trial straight
into the sampler (``make_trial(backend="mjx")``, and the C backend's own callback trial, which
then runs per shard on the host) and keeps the ``Simulator`` callback only for host-level
trials.
"""

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = [
    "CHAINS",
    "chain_mesh",
    "initialize_distributed",
    "is_main_process",
    "padded_size",
    "pad_chains",
    "put",
    "gather",
    "layout",
]

#: Name of the mesh axis the chain axis is sharded over.
CHAINS = "chains"


def chain_mesh(devices: Any) -> Mesh | None:
    """A 1-D mesh with axis ``"chains"``, or None for an unsharded run.

    Parameters
    ----------
    devices : None, "all", int, sequence of jax.Device, or jax.sharding.Mesh
        None: no sharding. ``"all"``: every device of every process (``jax.devices()``).
        ``n``: the first ``n`` of ``jax.devices()`` (single process only). A sequence: those
        devices. A Mesh: used as is; it must have a ``"chains"`` axis (other axes replicate).
    """
    if devices is None:
        return None
    if isinstance(devices, Mesh):
        if CHAINS not in devices.axis_names:
            raise ValueError(f"the mesh must have a {CHAINS!r} axis, got {devices.axis_names}")
        _check_processes(devices.devices.flat)
        return devices
    if isinstance(devices, str):
        if devices != "all":
            raise ValueError(f"devices must be None, 'all', an int, devices or a Mesh; "
                             f"got {devices!r}")
        devs = jax.devices()
    elif isinstance(devices, int | np.integer) and not isinstance(devices, bool):
        available = jax.devices()
        if not 1 <= devices <= len(available):
            raise ValueError(f"devices={devices} but {len(available)} device(s) are available")
        devs = available[: int(devices)]
    elif isinstance(devices, Sequence) and devices and all(
            isinstance(d, jax.Device) for d in devices):
        devs = list(devices)
        if len({d.id for d in devs}) != len(devs):
            raise ValueError("devices contains the same device twice")
    else:
        raise ValueError(f"devices must be None, 'all', an int, a non-empty sequence of "
                         f"jax devices or a Mesh; got {devices!r}")
    _check_processes(devs)
    return Mesh(np.asarray(devs), (CHAINS,))


def _check_processes(devs) -> None:
    # Every process runs the same program; one without a device in the mesh would hang.
    if jax.process_count() > 1:
        owners = {d.process_index for d in devs}
        if owners != set(range(jax.process_count())):
            raise ValueError(f"multi-process run: the mesh must include devices of every "
                             f"process, got devices of processes {sorted(owners)}")


def initialize_distributed(coordinator_address: str | None = None,
                           num_processes: int | None = None, process_id: int | None = None,
                           **kwargs) -> tuple[int, int]:
    """Join a multi-process JAX run (``jax.distributed.initialize``); returns (process, count).

    Call it before any other JAX call, on every host. With no arguments JAX reads
    ``JAX_COORDINATOR_ADDRESS`` (and detects SLURM, Open MPI, TPU pods, Kubernetes); otherwise
    pass ``coordinator_address="host0:1234"``, ``num_processes`` and this ``process_id``.
    Extra keyword arguments go to ``jax.distributed.initialize``. Calling it again is a no-op.
    """
    if not jax.distributed.is_initialized():
        jax.distributed.initialize(coordinator_address, num_processes, process_id, **kwargs)
    return jax.process_index(), jax.process_count()


def is_main_process() -> bool:
    """True on process 0: the one that writes results."""
    return jax.process_index() == 0


def padded_size(num_chains: int, mesh: Mesh) -> int:
    """``num_chains`` rounded up to a multiple of the mesh's ``"chains"`` axis size."""
    n = mesh.shape[CHAINS]
    return -(-num_chains // n) * n


def pad_chains(tree: Any, num_padded: int) -> Any:
    """Repeat the last chain along the leading axis of every leaf up to ``num_padded``.

    Padding chains copy the last real one (position, state); they cost a slot on the device
    and are dropped from every output.
    """
    def pad(x):
        extra = num_padded - x.shape[0]
        if extra == 0:
            return x
        return jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)], axis=0)

    return jax.tree.map(pad, tree)


def put(tree: Any, mesh: Mesh, spec: P) -> Any:
    """Place every array leaf of ``tree`` on ``mesh`` with ``spec``; other leaves pass through.

    Multi-process: every process must hold the same full value (same script, same seed);
    each contributes the shards its devices own.
    """
    sharding = NamedSharding(mesh, spec)

    def place(x):
        if x is None or not isinstance(x, jax.Array | np.ndarray):
            return x
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            data = place(jax.random.key_data(x))
            return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
        if jax.process_count() == 1:
            return jax.device_put(x, sharding)
        host = np.asarray(x)
        return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])

    return jax.tree.map(place, tree)


def gather(tree: Any, num_chains: int, axis: int = 0) -> Any:
    """The first ``num_chains`` entries along ``axis`` of every leaf, on this process's
    default device.

    The shards are copied to the host and assembled there, never with an XLA collective: on
    forced CPU devices a collective queued behind a long chunk can exceed XLA's rendezvous
    timeout. Arrays spanning several processes are all-gathered (``process_allgather``), so
    every process returns the full result.
    """
    def take(x):
        if x is None:
            return x
        if x.is_fully_addressable:
            host = np.asarray(x)
        else:
            host = multihost_utils.process_allgather(x, tiled=True)
        return jnp.asarray(host.take(np.arange(num_chains), axis=axis)
                           if host.shape[axis] != num_chains else host)

    return jax.tree.map(take, tree)


def layout(mesh: Mesh | None) -> dict:
    """The device layout of a run, for results files."""
    devs = jax.devices() if mesh is None else list(mesh.devices.flat)
    used = devs[:1] if mesh is None else devs
    return {
        "sharded": mesh is not None,
        "num_devices": len(used),
        "mesh_axes": None if mesh is None else dict(mesh.shape),
        "platform": used[0].platform,
        "device_kinds": sorted({d.device_kind for d in used}),
        "process_count": jax.process_count(),
        "process_index": jax.process_index(),
        "local_device_count": jax.local_device_count(),
    }
