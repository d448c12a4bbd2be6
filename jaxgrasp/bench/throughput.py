"""Trial throughput per physics backend: compile time apart from steady-state trials/s."""

import time

import numpy as np


def random_grasps(obj, n: int, seed: int = 0) -> np.ndarray:
    """``n`` gripper poses around ``obj``: positions in its bounding box inflated by 3 cm,
    uniform orientations (the same mix of outcomes a sketch sees)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(obj.mesh.bounds, float)
    pos = rng.uniform(lo - 0.03, hi + 0.03, size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.concatenate([pos, q], axis=1).astype(np.float32)


def measure(backend: str, obj_name: str, *, batch: int, seconds: float, seed: int = 0,
            bar=None) -> dict:
    """Time ``jax.jit(make_trial(scene, backend))`` on batches of random grasps.

    ``compile_s`` is the first call minus one steady-state call (tracing + XLA compile, or a
    hit in the persistent cache); ``trials_per_s`` counts calls for ``seconds`` afterwards
    (always at least one). Returns ``available=False`` with the error when the backend
    cannot be built here.
    """
    import jax

    from jaxgrasp import objects, physics

    rec = {"backend": backend, "object": obj_name, "batch": int(batch)}
    try:
        obj = objects.load(obj_name)
        scene = physics.load_scene(obj)
        trial = jax.jit(physics.make_trial(scene, backend=backend))
    except Exception as err:  # noqa: BLE001 - any failure means "not available here"
        return dict(rec, available=False, error=f"{type(err).__name__}: {err}")
    g = jax.numpy.asarray(random_grasps(obj, batch, seed))
    t0 = time.perf_counter()
    jax.block_until_ready(trial(g))
    first = time.perf_counter() - t0
    if bar is not None:
        bar.update(1)
    calls, t0 = 0, time.perf_counter()
    while True:
        gi = jax.numpy.asarray(random_grasps(obj, batch, seed + 1 + calls))
        jax.block_until_ready(trial(gi))
        calls += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            break
    per_call = elapsed / calls
    if bar is not None:
        bar.update(1)
    return dict(
        rec,
        available=True,
        compile_s=float(max(first - per_call, 0.0)),
        calls=int(calls),
        trials=int(calls * batch),
        seconds=float(elapsed),
        trials_per_s=float(calls * batch / elapsed),
    )
