"""What the public physics entry points accept: the backend name and grasp arrays.

Both checks run on the host before any JAX or MuJoCo code, so a bad argument is one clear
``ValueError`` naming the input and what to pass instead.
"""

from functools import partial

import jax
import numpy as np

__all__ = ["BACKENDS", "MIN_BUCKET", "PAD_GRASP", "bucket_size", "check_grasps", "pad_grasps",
           "resolve_backend", "take_rows"]

#: Physics backends of ``make_trial``; ``"auto"`` resolves to one of them.
BACKENDS = ("mjx", "mujoco", "mjx-warp")

#: Measured trials/s of each correct backend per JAX device kind, on the pitcher (full trial
#: with epsilon unless noted), with where each number comes from. ``"auto"`` takes the fastest
#: available backend of the device kind; a kind without measurements falls back to
#: :data:`UNMEASURED_DEFAULT`. Update from ``benchmarks/gpu_check.sh`` (GPU) and
#: ``benchmarks/throughput.py`` / ``benchmarks/backend_agreement.py --warp`` (CPU).
MEASURED_TRIALS_PER_S = {
    # 2-core AMD EPYC shared with other jobs (1-min load average 5-7), one run, B = 16,
    # pitcher, full trial, warm: `GPU_CHECK_TIMEOUT=1500 bash benchmarks/gpu_check.sh --quick
    # --budget-s 1400` (bench_out/gpu_check_cpu_quick.json). Absolute rates are low under
    # that load; the ratios (MJX 0.023 x C, MJX-Warp 0.015 x C) are what "auto" uses.
    "cpu": {"mujoco": 74.1, "mjx": 1.7, "mjx-warp": 1.1},
    # No GPU measurement yet (benchmarks/gpu_check.sh is untested on a GPU).
    "gpu": {},
    "tpu": {},
}

#: ``"auto"`` on a device kind without measurements: MJX (runs on any JAX device; MJX-Warp
#: needs warp-lang and CUDA, MuJoCo C runs on the host CPU only).
UNMEASURED_DEFAULT = "mjx"


def _available(backend: str) -> bool:
    if backend != "mjx-warp":
        return True
    # Function-local (reason: the optional warp probe loads MJX's Warp module; only asked for
    # "auto" on a kind whose table lists MJX-Warp).
    from mujoco.mjx import warp as mjxw

    return bool(mjxw.WARP_INSTALLED)


def resolve_backend(backend: str = "auto") -> str:
    """``"mjx"``, ``"mujoco"`` or ``"mjx-warp"`` for a requested backend name.

    ``"auto"``: the backend with the most trials/s measured on JAX's default device kind
    (:data:`MEASURED_TRIALS_PER_S`, among those installed): MuJoCo C on a CPU (MJX is ~40x,
    MJX-Warp ~65x slower there); MJX on a kind not measured yet. MuJoCo C is a dependency of
    the package (MJX is built on it), so it is always available.
    """
    if not isinstance(backend, str) or backend not in ("auto", *BACKENDS):
        raise ValueError(f"unknown physics backend {backend!r}; use 'auto' (the fastest "
                         f"measured on this device kind: MuJoCo C on a CPU), 'mjx', 'mujoco' "
                         f"or 'mjx-warp'")
    if backend != "auto":
        return backend
    table = MEASURED_TRIALS_PER_S.get(jax.default_backend(), {})
    ranked = sorted(table, key=table.get, reverse=True)
    return next((b for b in ranked if _available(b)), UNMEASURED_DEFAULT)


def check_grasps(grasps, name: str = "grasps", *, finite: bool = False,
                 allow_empty: bool = True):
    """Check a (B, 7) grasp array (x, y, z, qw, qx, qy, qz) before it reaches the physics.

    Integer and floating dtypes are accepted (the physics casts them to float32); bool,
    complex, strings and objects are refused, as is any other shape. ``finite=True`` (grasps
    given as data, e.g. demonstrations: not a sampler's proposals, whose non-finite or
    zero-quaternion values the trial protocol reports as failures) also refuses NaN/inf,
    values beyond float32 and a zero quaternion. Works on traced arrays (shape and dtype
    only). Returns ``grasps`` unchanged when it already has a shape and dtype, else a numpy
    array of it.
    """
    if not (hasattr(grasps, "shape") and hasattr(grasps, "dtype")):
        try:
            grasps = np.asarray(grasps)
        except (ValueError, TypeError) as err:
            raise ValueError(f"{name} must be a (B, 7) array of numbers, got "
                             f"{type(grasps).__name__}: {err}") from None
    kind = np.dtype(grasps.dtype).kind
    if kind not in "iuf":
        raise ValueError(f"{name} must hold integers or floats (cast to float32), got dtype "
                         f"{grasps.dtype}; pass a float array (x, y, z, qw, qx, qy, qz)")
    shape = tuple(grasps.shape)
    if len(shape) != 2 or shape[1] != 7 or (not allow_empty and shape[0] == 0):
        hint = "; for one grasp pass grasps[None]" if shape == (7,) else ""
        raise ValueError(f"{name} must have shape (B, 7) with B >= {0 if allow_empty else 1} "
                         f"(x, y, z, qw, qx, qy, qz per row), got {shape}{hint}")
    if finite:
        g = np.asarray(grasps, np.float64)
        bad = ~np.isfinite(g).all(axis=1) | (np.abs(g) > np.finfo(np.float32).max).any(axis=1)
        if bad.any():
            raise ValueError(f"{name}: {int(bad.sum())} of {len(g)} rows hold NaN/inf or values "
                             f"beyond float32 (first: row {int(np.argmax(bad))}); drop or fix them")
        zero = np.linalg.norm(g[:, 3:], axis=1) < 1e-6
        if zero.any():
            raise ValueError(f"{name}: {int(zero.sum())} of {len(g)} rows have a zero quaternion "
                             f"(first: row {int(np.argmax(zero))}); qw, qx, qy, qz must be a "
                             "rotation, e.g. 1, 0, 0, 0")
    return grasps


#: Smallest bucket of batch shapes (:func:`bucket_size`).
MIN_BUCKET = 8

#: The grasp that fills a padded batch: the gripper 100 m below the object's support plane, a
#: ``COLLISION`` decided from the corners alone (no collision pass, no rollout on MuJoCo C, no
#: epsilon), finite and placed far from everything on MJX (its rollout is wasted, never wrong).
PAD_GRASP = (0.0, 0.0, -100.0, 1.0, 0.0, 0.0, 0.0)


def bucket_size(n: int, min_bucket: int = MIN_BUCKET) -> int:
    """The padded batch size of ``n`` grasps: the power of two >= ``max(n, min_bucket)``.

    A session that runs 1...1024 grasps per call then compiles the trial at most
    ``log2(1024 / min_bucket) + 1`` times (8 with the default), not once per size.
    """
    n, min_bucket = int(n), int(min_bucket)
    if min_bucket < 1:
        raise ValueError(f"min_bucket must be >= 1, got {min_bucket}")
    return max(min_bucket, 1 << max(n - 1, 0).bit_length())


def pad_grasps(grasps, size: int):
    """``grasps`` (n, 7) followed by ``size - n`` rows of :data:`PAD_GRASP` (numpy float32).

    Trials are independent, so the padded rows change no result of the real ones.
    """
    with np.errstate(over="ignore"):  # a value beyond float32 becomes inf: flagged invalid
        g = np.asarray(grasps, np.float32)
    if size < g.shape[0]:
        raise ValueError(f"cannot pad {g.shape[0]} grasps to {size}")
    if size == g.shape[0]:
        return g
    pad = np.broadcast_to(np.asarray(PAD_GRASP, np.float32), (size - g.shape[0], 7))
    return np.concatenate([g, pad])


@partial(jax.jit, static_argnums=1)
def _take_rows(tree, n):
    return jax.tree.map(lambda x: x[:n], tree)


def take_rows(result, n: int):
    """The first ``n`` rows of every field of a padded result (one small compile per
    (bucket, n), not one per field)."""
    return result if result[0].shape[0] == n else _take_rows(result, int(n))

