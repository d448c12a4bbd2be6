"""Benchmark profiles: how much of the paper's protocol one ``python -m jaxgrasp.bench`` runs.

``smoke`` is for CI (every table cell type and every output, in minutes on 2 CPU cores),
the default is a meaningful reduced run (under 10 minutes on 2 CPU cores) and ``paper`` is
the full protocol of Table I (100 burn-in + 1000 iterations, several chains per cell).
"""

from dataclasses import dataclass, replace

from jaxgrasp.learn.evaluate.hold import PoseNoise

#: Table II columns, in the paper's order: (method, sketch) handed to ``jg.learn.active``.
ACTIVE_METHODS = {
    "random_walk": ("random_walk", "biased"),
    "kameleon_darting_random": ("kameleon_darting", "random"),
    "kameleon_darting_biased": ("kameleon_darting", "biased"),
}
ACTIVE_OBJECTS = ("pitcher", "pan", "plate")
#: Table III blocks (fixed names, contracts.md), rows in the order of the active set.
TRANSFER_SETS = {
    "transfer_a": ("tall_pitcher", "saucepan", "soup_plate"),
    "transfer_b": ("small_jug", "frying_pan", "platter"),
}
TRANSFER_MODES = ("source", "target")
#: The active-learning run whose chains and demos a transfer reuses (paper §6: the Markov
#: chains constructed when learning the similar object, i.e. the full workflow of exp. 3).
TRANSFER_SOURCE_METHOD = "kameleon_darting_biased"
BACKENDS = ("auto", "mjx", "mujoco")


@dataclass(frozen=True)
class Profile:
    """One benchmark configuration (no arrays; validated at construction).

    Attributes
    ----------
    name : str
    objects : tuple of str
        Active-set objects (Table II rows); Table III rows are their transfer counterparts.
    transfer_sets : tuple of str
        Which Table III blocks to run (subset of ``TRANSFER_SETS``).
    chains : int
        Independent chains per cell; each chain is one run of ``burn_in + iterations`` proposals.
    iterations, burn_in : int
        Per chain; the tables count every proposal of both phases.
    backend : str
        ``"auto"`` (MJX on an accelerator, MuJoCo C on a CPU), ``"mjx"`` or ``"mujoco"``.
    seed : int
    params : tuple of (str, value) pairs
        Overrides of the learning parameters (``jg.learn`` params) for cheaper profiles.
    checkpoint_every : int
        Learn checkpoints every this many steps (0: none); a killed long run resumes.
    throughput_seconds : float
        Wall time spent timing the run's backend after compilation (batch = chains, the
        experiments' own compiled trial); only the backend the experiments use is measured.
    robust_tries : int
        Tries per distinct successful grasp of each cell under the robot's pose error
        (``jg.learn.robustness``, after learning, on the cell's own trial); 0: not measured.
    pose_error : (float, float)
        That pose error: position sd (mm, per axis) and orientation sd (degrees).
    description : str
    """

    name: str
    objects: tuple = ACTIVE_OBJECTS
    transfer_sets: tuple = tuple(TRANSFER_SETS)
    chains: int = 4
    iterations: int = 1000
    burn_in: int = 100
    backend: str = "auto"
    seed: int = 0
    params: tuple = ()
    checkpoint_every: int = 0
    throughput_seconds: float = 5.0
    robust_tries: int = 0
    pose_error: tuple = (3.0, 3.0)
    description: str = ""

    def __post_init__(self):
        bad = [o for o in self.objects if o not in ACTIVE_OBJECTS]
        if not self.objects or bad:
            raise ValueError(
                f"objects must be a non-empty subset of {ACTIVE_OBJECTS}, got {self.objects!r}"
            )
        bad = [s for s in self.transfer_sets if s not in TRANSFER_SETS]
        if bad:
            raise ValueError(f"unknown transfer set(s) {bad}; known: {tuple(TRANSFER_SETS)}")
        if self.chains < 1:
            raise ValueError(f"chains must be >= 1, got {self.chains}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.iterations < 1 or self.burn_in < 0:
            raise ValueError(
                f"need iterations >= 1 and burn_in >= 0, got {self.iterations}, {self.burn_in}"
            )
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.checkpoint_every < 0:
            raise ValueError(f"checkpoint_every must be >= 0, got {self.checkpoint_every}")
        if self.throughput_seconds < 0:
            raise ValueError(f"throughput_seconds must be >= 0, got {self.throughput_seconds}")
        if self.robust_tries < 0:
            raise ValueError(f"robust_tries must be >= 0, got {self.robust_tries}")
        if len(self.pose_error) != 2:
            raise ValueError(f"pose_error must be (mm, degrees), got {self.pose_error!r}")
        PoseNoise(position_sd=self.pose_error[0] / 1000.0, angle_sd=self.pose_error[1]).check()

    @property
    def proposals(self) -> int:
        """Proposals per run (per chain): what one table row's columns sum to."""
        return self.burn_in + self.iterations

    @property
    def noise(self) -> PoseNoise | None:
        """The pose error the cells' grasps are tried under, or None (not measured)."""
        if not self.robust_tries:
            return None
        mm, deg = self.pose_error
        return PoseNoise(position_sd=mm / 1000.0, angle_sd=float(deg), tries=self.robust_tries)

    def transfer_objects(self, transfer_set: str) -> tuple:
        """Table III rows of ``transfer_set`` whose similar active object is being run."""
        pairs = zip(ACTIVE_OBJECTS, TRANSFER_SETS[transfer_set], strict=True)
        return tuple(t for a, t in pairs if a in self.objects)

    def with_overrides(self, **kw) -> "Profile":
        """A copy with the CLI flags that were given (``None`` means keep)."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})


PROFILES = {
    # CI: one object, one transfer block, tiny chains; every cell type and output still runs.
    "smoke": Profile(
        name="smoke",
        # Pitcher: with this gripper the plate's 2 cm rim yields no holding grasp (demos fail).
        objects=("pitcher",),
        transfer_sets=("transfer_a",),
        chains=2,
        iterations=12,
        burn_in=4,
        params=(("sketch_size", 32), ("subsample_size", 16)),
        throughput_seconds=1.0,
        description="CI check: every cell type and output, tiny budget",
    ),
    "default": Profile(
        name="default",
        chains=4,
        iterations=100,
        burn_in=20,
        params=(("sketch_size", 200),),
        throughput_seconds=5.0,
        description="reduced run: all cells, 120 proposals per chain",
    ),
    "paper": Profile(
        name="paper",
        chains=8,
        iterations=1000,
        burn_in=100,
        checkpoint_every=100,
        throughput_seconds=20.0,
        description="full protocol of Table I: 100 burn-in + 1000 iterations per chain",
    ),
}


def get_profile(name: str) -> Profile:
    """The named profile; ValueError listing the known ones otherwise."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown profile {name!r}; known: {sorted(PROFILES)}") from None


def parse_objects(spec: str) -> tuple:
    """``"pitcher,plate"`` -> ``("pitcher", "plate")``; transfer names map to their kind's
    active object (``soup_plate`` -> ``plate``) so either spelling selects the row pair."""
    names = [s.strip() for s in spec.split(",")]
    if "" in names:
        raise ValueError(f"--objects {spec!r} has an empty name; give comma-separated names "
                         "without spaces or empty entries, e.g. pitcher,pan")
    out = []
    for n in names:
        if n in ACTIVE_OBJECTS:
            a = n
        else:
            a = next(
                (ACTIVE_OBJECTS[i] for objs in TRANSFER_SETS.values() for i, t in
                 enumerate(objs) if t == n),
                None,
            )
            if a is None:
                known = ACTIVE_OBJECTS + sum(TRANSFER_SETS.values(), ())
                raise ValueError(f"unknown object {n!r}; known: {', '.join(known)}")
        if a not in out:
            out.append(a)
    if not out:
        raise ValueError("--objects is empty")
    return tuple(o for o in ACTIVE_OBJECTS if o in out)
