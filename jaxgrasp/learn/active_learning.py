"""Active learning of grasps (paper §4, experiments 1-3) and the chain runner shared by all runs.

Protocol of one run: make ``num_demos`` demonstrated grasps (the GDMC modes), build the rough
sketch, start the chains at the demos (chain ``c`` at demo ``c mod m``) and run
``burn_in + iterations`` steps; Kameleon adapts during the burn-in. Every proposal is one
physics trial and is counted (success / slipped / collision / miss), burn-in included, as in
the paper's tables (1100 proposals per run). The outcome of a proposal is read from the
density's aux in the step info: it is never simulated twice.
"""

import time

import jax
import numpy as np

from jaxgrasp.learn.checkpoint import CheckpointDir, state_from_arrays, state_to_arrays
from jaxgrasp.learn.demos import demonstrations
from jaxgrasp.learn.metric import GraspMetric
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.results import Demos, LearnResult, demo_result_arrays, demo_results_from_arrays
from jaxgrasp.learn.results import load as load_result
from jaxgrasp.learn.sim import Simulator, as_simulator, run_backend, target_logdensity

__all__ = ["active", "make_algorithm", "run_chains", "METHODS", "SKETCHES"]

METHODS = ("random_walk", "kameleon_darting")
SKETCHES = ("random", "biased")
#: Steps per jitted chunk (progress and checkpoint granularity); one size for every phase so
#: the sketch run, the main run and resumed runs share one compiled scan.
DEFAULT_CHUNK = 10
#: Smallest variance of a GDMC region axis: (1 mm)^2 in position, 1e-6 per quaternion component.
REGION_VAR_FLOOR = 1e-6
HISTORY = ("positions", "proposals", "outcomes", "epsilons", "accepted", "is_jump")


def resolve_params(params, *, iterations=None, burn_in=None) -> LearnParams:
    """``params`` (default Table I) with ``iterations``/``burn_in`` overrides applied."""
    if params is None:
        params = LearnParams()
    if not isinstance(params, LearnParams):
        raise ValueError(f"params must be a LearnParams, got {type(params).__name__}")
    changes = {k: v for k, v in (("iterations", iterations), ("burn_in", burn_in))
               if v is not None}
    return params.replace(**changes) if changes else params


def resolve_object(obj):
    """A GraspObject from a name, a Scene or a GraspObject."""
    if isinstance(obj, str):
        from jaxgrasp import objects

        return objects.load(obj)
    obj = getattr(obj, "obj", obj)
    if not hasattr(obj, "mesh") or not hasattr(obj, "content_hash"):
        raise ValueError(f"expected a GraspObject, a Scene or an object name, got {obj!r}")
    return obj


def check_seed(seed) -> int:
    if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def check_chains(chains) -> int:
    if not isinstance(chains, int | np.integer) or isinstance(chains, bool) or chains < 1:
        raise ValueError(f"chains must be a positive int, got {chains!r}")
    return int(chains)


def make_algorithm(method: str, sim: Simulator, params: LearnParams, *, sketch=None,
                   modes=None, traced: bool = False):
    """The sampler of a run: random walk on grasps, or Kameleon + GDMC on the lifted R^7 target.

    Parameters
    ----------
    method : "random_walk" or "kameleon_darting"
    sim : Simulator
        The object's compiled trial; the target is ``log(epsilon + floor)`` on its trials.
    params : LearnParams
    sketch : (n, 7) array
        Kameleon's rough sketch (kameleon_darting only).
    modes : (m, 7) array
        GDMC modes: the demonstrated grasps (kameleon_darting only).
    traced : bool
        Trace ``sim.trial`` into the sampler instead of reaching it through the host callback:
        with chains sharded over devices, MJX rollouts then run on every device (the callback
        would run them all on the default device). Compiles the physics with the sampler.
    """
    from jaxgrasp import mcmc

    if traced:
        sim = _TracedTarget(sim)
    if method == "random_walk":
        logdensity = sim.logdensity(floor=params.density_floor, slip_weight=params.slip_weight)
        return mcmc.random_walk(logdensity, position_scale=params.position_scale,
                                kappa=params.kappa)
    if method == "kameleon_darting":
        if sketch is None or modes is None:
            raise ValueError("kameleon_darting needs a sketch and modes")
        metric = sampler_metric(method, params)
        # Kameleon's Gaussian proposals leave the unit sphere: sample the lifted R^7 target.
        logdensity = metric.wrap(sim.logdensity(floor=params.density_floor, lifted=True,
                                                width=params.lift_width,
                                                slip_weight=params.slip_weight))
        sketch = metric.to_sampler(sketch)
        sigma, nu = params.kameleon_scales(sketch)
        region_cov = (region_covariance(sketch) if params.region_scale is None
                      else params.region_scale**2 * np.eye(7, dtype=np.float32))
        return mcmc.kameleon_darting(
            logdensity, sketch, metric.to_sampler(modes),
            region_cov=region_cov, p_check=params.p_check, epsilon=params.epsilon,
            gamma=params.gamma, nu=nu, sigma=sigma,
            subsample_size=params.subsample_size, adapt_steps=params.burn_in,
            target_acceptance=params.target_acceptance, uniform_jumps=params.uniform_jumps)
    raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")


class _TracedTarget:
    """``sim.logdensity`` built on ``sim.trial`` itself (no host callback); equal arguments
    give equal (hashable) targets, so rebuilt samplers share their compiled code."""

    def __init__(self, sim):
        self.trial = sim.trial

    def logdensity(self, **kw):
        return target_logdensity(self.trial, **kw)


def sampler_metric(method: str, params: LearnParams) -> GraspMetric:
    """The sampler's coordinates of a run: scaled for Kameleon + GDMC, raw for the walk."""
    return GraspMetric(params.length_scale if method == "kameleon_darting" else 1.0)


def is_traceable(sim: Simulator) -> bool:
    """Whether ``sim.trial`` can be traced into a sampler (MJX, or a callback-based trial)."""
    sim.result_shapes(1)
    return bool(sim._traceable)


def open_run(checkpoint_dir, config: dict, obj):
    """``(checkpoint dir or None, finished result or None)`` for a run with ``config``."""
    if checkpoint_dir is None:
        return None, None
    ckpt = CheckpointDir(checkpoint_dir, config)
    return ckpt, (load_result(ckpt.dir, obj) if ckpt.has_result() else None)


def simulator_batch(chains: int, devices) -> int:
    """The Simulator batch size: all chains, or the chains of one device when sharded."""
    if devices is None:
        return chains
    from jaxgrasp.mcmc import sharding

    mesh = sharding.chain_mesh(devices)
    return sharding.padded_size(chains, mesh) // mesh.shape[sharding.CHAINS]


def region_covariance(sketch, floor: float = REGION_VAR_FLOOR) -> np.ndarray:
    """GDMC's shared region covariance: the sketch covariance, eigenvalues floored at ``floor``.

    The paper uses the covariance of the Markov chain (the sketch). A short chain history (a
    small transfer source) can be degenerate in some directions; flooring the spectrum keeps the
    ellipsoids proper and changes nothing for a well-spread sketch.
    """
    x = np.asarray(sketch, np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"the sketch must be (n >= 2, d), got shape {x.shape}")
    cov = np.cov(x, rowvar=False)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    return ((vec * np.maximum(lam, floor)) @ vec.T).astype(np.float32)


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
    positions = np.asarray(positions)
    hi = lo + positions.shape[0]
    aux = infos.aux
    hist["positions"][lo:hi] = metric.to_grasp(positions)
    hist["proposals"][lo:hi] = metric.to_grasp(infos.proposal)
    hist["outcomes"][lo:hi] = np.asarray(aux["outcome"])
    hist["epsilons"][lo:hi] = np.asarray(aux["epsilon"])
    hist["accepted"][lo:hi] = np.asarray(infos.is_accepted)
    is_jump = getattr(infos, "is_jump", None)
    hist["is_jump"][lo:hi] = False if is_jump is None else np.asarray(is_jump)
    return hi


def run_chains(alg, key, initial_positions, num_steps: int, *, checkpoint: CheckpointDir = None,
               checkpoint_every: int | None = None, progress: bool = True, desc: str = "",
               devices=None, metric: GraspMetric | None = None):
    """Run ``alg`` on C chains for ``num_steps`` steps, recording every proposal's outcome.

    With ``checkpoint``, the sampler state and the history so far are saved every
    ``checkpoint_every`` steps, and a run finding a checkpoint continues from it; the result
    is bit-identical to an uninterrupted run (per-step keys depend on the global step only).
    ``metric``: the sampler's coordinates (:func:`sampler_metric`); the initial positions and
    the returned history are grasps.

    Returns
    -------
    dict of numpy arrays: positions (S, C, 7), proposals (S, C, 7), outcomes (S, C) int8,
    epsilons (S, C), accepted (S, C), is_jump (S, C).
    """
    from tqdm.auto import tqdm

    from jaxgrasp import mcmc

    metric = GraspMetric() if metric is None else metric
    init = metric.to_sampler(initial_positions)
    chains = init.shape[0]
    hist = empty_history(num_steps, chains)
    start, state = 0, None
    if checkpoint is not None:
        start, arrays = checkpoint.load_state()
        if arrays is not None:
            for name in HISTORY:
                if arrays[name].shape != hist[name].shape:
                    raise ValueError(f"checkpoint history {name!r} has shape "
                                     f"{arrays[name].shape}, expected {hist[name].shape}")
                hist[name][...] = arrays[name]
            template = jax.eval_shape(jax.vmap(alg.init), init)
            state = state_from_arrays(arrays, template)
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
                    devices=devices)
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


def active(obj, *, method="kameleon_darting", sketch="biased", chains=4, iterations=None,
           burn_in=None, seed=0, params=None, backend="auto", checkpoint_dir=None,
           checkpoint_every=None, progress=True, trial=None, devices=None,
           demos=None) -> LearnResult:
    """Active learning of grasps for a known object (paper experiments 1-3).

    Parameters
    ----------
    obj : GraspObject, Scene or str
    method : {"random_walk", "kameleon_darting"}
        Experiment 1 (baseline) or Kameleon MCMC combined with GDMC jumps.
    sketch : {"random", "biased"}
        Kameleon's rough sketch: uniformly random poses (experiment 2) or the proposals of a
        random-walk run from the demos (experiment 3). Ignored by the random walk.
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
        Show a tqdm progress bar.
    trial : Simulator or callable, optional
        A prebuilt trial of ``obj`` (shares compiled physics across runs).
    devices : None, "all", int, devices or Mesh, optional
        Shard the chains of the main run over these devices (``jg.mcmc.sample(devices=)``).
        A traceable trial (MJX) is then traced into the sampler so every device runs the
        rollouts of its own chains; a host-level trial stays a host callback, called once per
        device shard. Demos and the sketch run are not sharded. Multi-host: see
        ``jg.mcmc.sharding``.

    Returns
    -------
    LearnResult
    """
    backend = run_backend(backend, trial)
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
    if sketch not in SKETCHES:
        raise ValueError(f"unknown sketch {sketch!r}; expected one of {SKETCHES}")
    params = resolve_params(params, iterations=iterations, burn_in=burn_in)
    seed, chains = check_seed(seed), check_chains(chains)
    _check_every(checkpoint_every)
    obj = resolve_object(obj)
    sketch_kind = sketch if method == "kameleon_darting" else "none"
    config = {"workflow": "active", "object": obj.name, "object_hash": obj.content_hash,
              "method": method, "sketch": sketch_kind, "chains": chains, "seed": seed,
              "backend": backend, "params": params.to_dict()}
    ckpt, done = open_run(checkpoint_dir, config, obj)
    if done is not None:
        return done
    sim = as_simulator(obj, backend=backend, trial=trial,
                       batch_size=simulator_batch(chains, devices))
    t0 = time.perf_counter()
    setup = ckpt.load_setup() if ckpt is not None else None
    if setup is None:
        key = jax.random.key(seed)
        if demos is None:
            demos = demonstrations(obj, num=params.num_demos, seed=seed, trial=sim,
                                   params=params)
        else:
            demos = check_demos(demos)
        if method == "random_walk":
            sketch_points = np.zeros((0, 7), np.float32)
        elif sketch == "random":
            from jaxgrasp.learn.sketch import random_sketch

            sketch_points = random_sketch(sim.scene or obj, jax.random.fold_in(key, 1),
                                          params.sketch_size)
        else:
            from jaxgrasp.learn.sketch import biased_sketch

            sketch_points = biased_sketch(obj, jax.random.fold_in(key, 1), params.sketch_size,
                                          demos=demos, params=params, chains=chains, trial=sim,
                                          progress=progress)
        setup = {"demo_poses": demos.poses, "sketch_points": sketch_points,
                 **demo_result_arrays(demos.results)}
        if ckpt is not None:
            ckpt.save_setup(setup)
    demos = Demos(setup["demo_poses"], demo_results_from_arrays(setup))
    modes = np.asarray(demos.poses, np.float32)
    init = modes[np.arange(chains) % len(modes)]
    setup_s = time.perf_counter() - t0
    alg = make_algorithm(method, sim, params, sketch=setup["sketch_points"], modes=modes,
                         traced=devices is not None and is_traceable(sim))
    t1 = time.perf_counter()
    hist = run_chains(alg, jax.random.fold_in(jax.random.key(seed), 2), init,
                      params.num_steps, checkpoint=ckpt, checkpoint_every=checkpoint_every,
                      devices=devices, progress=progress, metric=sampler_metric(method, params),
                      desc=f"{obj.name} {method}"
                      + (f" ({sketch} sketch)" if method == "kameleon_darting" else ""))
    result = LearnResult(
        object_name=obj.name, object_hash=obj.content_hash, workflow="active", method=method,
        sketch=sketch_kind, modes_kind="demos" if method == "kameleon_darting" else "none",
        seed=seed, backend=backend, params=params, **hist, initial_positions=init,
        modes=modes, sketch_points=setup["sketch_points"], demos=demos,
        info={"setup_seconds": setup_s, "run_seconds": time.perf_counter() - t1},
    )
    if ckpt is not None:
        result.save(ckpt.dir)
    return result


def check_demos(demos) -> Demos:
    """Validate precomputed demonstrations (a ``Demos`` with at least one (m, 7) pose)."""
    if not isinstance(demos, Demos):
        raise ValueError(f"demos must be a jg.learn.Demos, got {type(demos).__name__}")
    poses = np.asarray(demos.poses, np.float32)
    if poses.ndim != 2 or poses.shape[1] != 7 or len(poses) == 0:
        raise ValueError(f"demos.poses must be a non-empty (m, 7) array, got {poses.shape}")
    return Demos(poses, demos.results)


def _check_every(every):
    if every is not None and (not isinstance(every, int | np.integer) or isinstance(every, bool)
                              or every < 1):
        raise ValueError(f"checkpoint_every must be a positive int or None, got {every!r}")
