"""Parameters of the learning workflows: the paper's Table I plus the pieces it leaves open."""

import dataclasses
import math
from dataclasses import dataclass

from jaxgrasp.density import ESTIMATES
from jaxgrasp.mcmc import median_heuristic
from jaxgrasp.objects.symmetry import Symmetry

__all__ = ["DEMO_CHOICES", "LearnParams", "NU_CONVENTIONS"]

NU_CONVENTIONS = ("gradient_step", "literal")
#: ``LearnParams.demo_choice``: the search's first successes, spread ones, or antipodal ones.
DEMO_CHOICES = ("first", "spread", "antipodal")


@dataclass(frozen=True)
class LearnParams:
    """Configuration of active and transfer learning.

    The defaults are the settings that learn the most distinct new grasps (measured in
    ``docs/design.md``, "Exploration: why the defaults differ from Table I"); :meth:`paper`
    gives Table I's. They differ in
    ``gamma`` (1e-4 -> 0.05), ``p_check`` (0.6 -> 0.9), ``density_floor`` (1e-4 -> 1e-6),
    ``length_scale`` (1 -> 0.115 m), ``target_acceptance`` (None -> 0.3), ``slip_weight``
    (1 -> 0.01), ``axis_moves`` (0 -> 0.5 of the local steps turn about the object's z axis),
    ``pivot_share`` (0 -> half of those turns pivot about the gripper's closing axis),
    ``symmetry_share`` (0 -> a quarter of the turns reflect the grasp through the object's
    mirror planes or turn it by its n-fold symmetry, where the mesh has them) and
    ``slip_scale`` (0 -> 2 mm: grasps the object moves in during the hold weigh less, so the
    chains find more grasps that hold under a robot's pose error).

    Attributes
    ----------
    iterations : int
        MCMC iterations after burn-in (Table I: 1000).
    burn_in : int
        Burn-in iterations; Kameleon adapts its subsample during them (Table I: 100). Every
        proposal, burn-in included, is counted in the outcome tables (1100 per run).
    gamma : float
        Kameleon's isotropic exploration noise gamma (Table I: 1e-4).
    subsample_size : int
        Kameleon's kernel subsample size n (Table I: 100).
    nu : float
        Kameleon's scale nu (Table I: 2.38 / sqrt(6), a 6-DoF pose).
    p_check : float
        GDMC: probability of a local step; a jump is attempted with 1 - p_check (Table I: 0.6).
    epsilon : float
        GDMC jump-region radius in Mahalanobis units (Table I: 0.7).
    num_demos : int
        Number of demonstrated grasps, the GDMC modes (paper: 5).
    position_scale : float
        Random walk: std of the Gaussian position proposal in metres (the paper's Sigma, not
        given there).
    kappa : float
        Random walk: concentration of the von Mises-Fisher orientation proposal on S^3 (not
        given in the paper). kappa = 50 moves the gripper by about 25 degrees per step.
    sketch_size : int
        Number of poses in the rough sketch handed to Kameleon (random sketch, biased sketch,
        or the thinned source chain history in transfer learning).
    density_floor : float
        Floor of the target density, log pi = log(epsilon + floor): keeps MH defined where no
        grasp holds (there the chain is a random walk, as in the paper).
    lift_width : float
        Width of the log-normal radial density on |q| of the lifted R^7 target (Kameleon).
    demo_candidates : int
        Candidate surface points per wanted demonstration; only demos whose physics trial
        succeeds are kept.
    demo_fallback : {"none", "slipped"}
        When fewer than ``num_demos`` candidates succeed: keep fewer ("none", the paper's
        protocol) or top up with the slipped candidates of highest epsilon ("slipped").
    kernel_sigma : float or None
        Width of Kameleon's Gaussian kernel in the R^7 sampler space; None: the median
        heuristic on the sketch (Sejdinovic et al.).
    nu_convention : {"gradient_step", "literal"}
        How Table I's nu enters the proposal ``N(y, gamma^2 I + nu^2 M H M^T)``. The paper
        writes ``M = 2 eta [grad k(y, z_i)]_i`` with a gradient step eta. ``"literal"`` takes
        eta = 1: then M has units 1/length and n columns, the kernel part's std is about
        ``nu sqrt(n) / sigma`` and, with a median-heuristic sigma < 1 on grasp sketches,
        local steps are metres long. ``"gradient_step"`` (default) takes eta = sigma^2 / 2
        and averages over the subsample (``nu_sampler = nu sigma^2 / (2 sqrt(n))``): the
        proposal covariance is then ``nu^2`` times a kernel-weighted local covariance of the
        sketch, so 2.38/sqrt(6) has its usual adaptive-Metropolis meaning.
    length_scale : float
        Kameleon + GDMC sample ``(pos / length_scale, q)`` (:mod:`jaxgrasp.learn.metric`): the
        kernel, gamma, sigma and the jump regions then weigh position and orientation alike.
        1.0 is the paper's raw metres-and-quaternion space.
    target_acceptance : float or None
        Adapt the local proposal's scale (gamma and nu together) per chain during burn-in
        toward this acceptance rate (Robbins-Monro), frozen after; None: fixed (the paper).
    region_scale : float or None
        GDMC regions: None is the paper's shared sketch covariance; a number gives every mode
        an isotropic region of this standard deviation in sampler units (radius
        ``epsilon * region_scale``), the size of a grasp basin.
    uniform_jumps : bool
        GDMC jumps land on a uniform point of the target region instead of the mapped one (a
        chain resting on a demo otherwise re-proposes the other demos exactly).
    slip_weight : float
        Weight of a slipped grasp's epsilon in the target density; 1.0 is the paper's
        ``pi ∝ epsilon`` for holding and slipping grasps alike.
    epsilon_power : float
        Exponent in (0, 1] on epsilon in the target, ``pi ∝ w epsilon^power + floor``; 1.0 is
        the paper's. Below 1 the chains spread over the holding grasps instead of piling up
        on the few of highest epsilon.
    axis_moves : float
        Kameleon + GDMC: share of the local (non-jump) steps that turn the grasp about the
        object frame's z axis instead (:mod:`jaxgrasp.mcmc.symmetry`); a step turns with
        probability ``axis_moves * p_check`` (0.45 with the defaults). 0 is the paper's sampler.
        Shipped objects are solids of revolution about z, so a holding grasp turned about it
        holds again away from the handle; set 0 for an object with no such axis (the turns
        are then mostly rejected trials).
    axis_angle : float
        Standard deviation of that turn (radians).
    pivot_share : float
        Share of those turns that pivot the grasp about the gripper's own closing axis through
        the grasp centre instead (:data:`jaxgrasp.mcmc.symmetry.PIVOT_PLANES`): the pads keep
        their contact points while the approach direction tilts. Needs no object symmetry.
    pivot_angle : float
        Standard deviation of a pivot (radians).
    slide_share : float
        Share of the turns that slide the grasp along its own approach axis instead
        (:data:`jaxgrasp.mcmc.symmetry.APPROACH_SLIDE`): a deeper or shallower grasp at the
        same place; ``pivot_share + slide_share <= 1``.
    slide_distance : float
        Standard deviation of a slide (metres).
    symmetry : str
        The object's symmetry about a vertical axis: ``"auto"`` (found from the mesh,
        :func:`jaxgrasp.objects.find_symmetry`) or a user's override
        (:meth:`jaxgrasp.objects.Symmetry.parse`: ``"none"``, ``"revolution"``, ``"turns:N"``,
        each optionally ``"@X,Y"``). The turns about a vertical axis go through its axis (an
        object with none: through the centre of mass); its n-fold turns and mirror planes
        are the moves of ``symmetry_share``.
    symmetry_share : float
        Share of the turns that map the grasp by one of the object's own symmetries instead:
        a reflection through a vertical mirror plane or an n-fold turn
        (:class:`jaxgrasp.mcmc.symmetry.Mirror`, :class:`~jaxgrasp.mcmc.symmetry.Turn`; none
        for a solid of revolution, whose continuous turns already are); ``pivot_share +
        slide_share + symmetry_share <= 1``.
    robust_tries : int
        Perturbed tries per proposal (0: the paper's one trial). With k tries every proposal
        is simulated with k copies under the pose error below, in one batch, and the target is
        its quality smoothed over that error, sampled exactly (pseudo-marginal MH, see
        ``jaxgrasp.density``): the chains seek grasps that hold when the robot misses a bit.
        Each proposal then costs k + 1 trials.
    robust_position_sd, robust_angle_sd : float
        The pose error of those tries: metres per axis and degrees (``jg.learn.PoseNoise``).
    robust_estimate : {"mean", "all_held"}
        What the tries estimate (``jg.density.GraspLogDensity``): the quality smoothed over
        the pose error, or the quality times the chance that every try holds.
    slip_scale : float
        Metres; above 0 the target weighs each grasp by ``exp(-displacement / slip_scale)``,
        the object's largest displacement relative to the gripper during the hold (0: the
        paper's density). Costs no trial. 2 mm (the default) gives more distinct grasps that
        hold under 3 mm / 3° of pose error than 0, for fewer distinct grasps in all
        (``docs/design.md``, "Grasps that hold under a robot's pose error").
    spread_starts : bool
        Chains beyond the m demos start at the demo search's other distinct successes
        (``Demos.spares``) instead of cycling over the demos (False: the paper's starts).
    demo_choice : {"first", "spread", "antipodal"}
        Which of the demo search's successes become the demos: the first ``num_demos`` in
        candidate order, or ``num_demos`` spread over the object (farthest apart in the grasp
        metric, ``length_scale``) among every success of the rounds the search ran (same
        trials either way), or spread the same way among the successes of
        ``num_demos x 40`` collision-free antipodal grasps (a pan's handle too), the
        candidate search's first ones where fewer than ``num_demos`` of those succeed.
    """

    iterations: int = 1000
    burn_in: int = 100
    gamma: float = 0.05
    subsample_size: int = 100
    nu: float = 2.38 / math.sqrt(6.0)
    p_check: float = 0.9
    epsilon: float = 0.7
    num_demos: int = 5
    position_scale: float = 0.02
    kappa: float = 50.0
    sketch_size: int = 1000
    density_floor: float = 1e-6
    lift_width: float = 0.05
    demo_candidates: int = 8
    demo_fallback: str = "none"
    kernel_sigma: float | None = None
    nu_convention: str = "gradient_step"
    length_scale: float = 0.01 / math.sin(math.radians(5.0))
    target_acceptance: float | None = 0.3
    region_scale: float | None = None
    uniform_jumps: bool = False
    slip_weight: float = 0.01
    epsilon_power: float = 1.0
    axis_moves: float = 0.5
    axis_angle: float = 1.0
    pivot_share: float = 0.5
    pivot_angle: float = 0.3
    slide_share: float = 0.0
    slide_distance: float = 0.01
    symmetry: str = "auto"
    symmetry_share: float = 0.25
    robust_tries: int = 0
    robust_position_sd: float = 0.003
    robust_angle_sd: float = 3.0
    robust_estimate: str = "mean"
    slip_scale: float = 0.002
    spread_starts: bool = False
    demo_choice: str = "first"

    def __post_init__(self):
        for name in ("iterations", "subsample_size", "num_demos", "sketch_size",
                     "demo_candidates"):
            _check_int(name, getattr(self, name), minimum=1)
        _check_int("burn_in", self.burn_in, minimum=0)
        _check_int("robust_tries", self.robust_tries, minimum=0)
        if self.robust_estimate not in ESTIMATES:
            raise ValueError(f"LearnParams.robust_estimate must be one of {ESTIMATES}, got "
                             f"{self.robust_estimate!r}")
        for name in ("gamma", "nu", "epsilon", "position_scale", "kappa", "density_floor",
                     "lift_width", "length_scale"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise ValueError(f"LearnParams.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"LearnParams.{name} must be finite and > 0, got {value!r}")
        if self.kernel_sigma is not None and not (
                isinstance(self.kernel_sigma, int | float) and math.isfinite(self.kernel_sigma)
                and self.kernel_sigma > 0):
            raise ValueError(f"LearnParams.kernel_sigma must be None or finite and > 0, got "
                             f"{self.kernel_sigma!r}")
        for name in ("target_acceptance", "region_scale"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int | float)
                                          and math.isfinite(value) and value > 0):
                raise ValueError(f"LearnParams.{name} must be None or finite and > 0, got "
                                 f"{value!r}")
        if self.target_acceptance is not None and not self.target_acceptance < 1:
            raise ValueError(f"LearnParams.target_acceptance must be < 1, got "
                             f"{self.target_acceptance!r}")
        for name in ("uniform_jumps", "spread_starts"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"LearnParams.{name} must be a bool, got "
                                 f"{getattr(self, name)!r}")
        if not (isinstance(self.slip_weight, int | float) and 0.0 <= self.slip_weight <= 1.0):
            raise ValueError(f"LearnParams.slip_weight must lie in [0, 1], got "
                             f"{self.slip_weight!r}")
        if not (isinstance(self.epsilon_power, int | float) and 0.0 < self.epsilon_power <= 1.0):
            raise ValueError(f"LearnParams.epsilon_power must lie in (0, 1], got "
                             f"{self.epsilon_power!r}")
        if self.demo_choice not in DEMO_CHOICES:
            raise ValueError(f"LearnParams.demo_choice must be one of {DEMO_CHOICES}, got "
                             f"{self.demo_choice!r}")
        if self.demo_fallback not in ("none", "slipped"):
            raise ValueError(f"LearnParams.demo_fallback must be 'none' or 'slipped', got "
                             f"{self.demo_fallback!r}")
        if self.nu_convention not in NU_CONVENTIONS:
            raise ValueError(f"LearnParams.nu_convention must be one of {NU_CONVENTIONS}, got "
                             f"{self.nu_convention!r}")
        if not isinstance(self.p_check, int | float) or not 0.0 <= self.p_check <= 1.0:
            raise ValueError(f"LearnParams.p_check must lie in [0, 1], got {self.p_check!r}")
        if not (isinstance(self.axis_moves, int | float) and 0.0 <= self.axis_moves <= 1.0):
            raise ValueError(f"LearnParams.axis_moves must lie in [0, 1], got "
                             f"{self.axis_moves!r}")
        if not (isinstance(self.pivot_share, int | float) and 0.0 <= self.pivot_share <= 1.0):
            raise ValueError(f"LearnParams.pivot_share must lie in [0, 1], got "
                             f"{self.pivot_share!r}")
        if not (isinstance(self.slide_share, int | float) and 0.0 <= self.slide_share
                and self.pivot_share + self.slide_share <= 1.0):
            raise ValueError(f"LearnParams.slide_share must lie in [0, 1 - pivot_share], got "
                             f"{self.slide_share!r}")
        if not (isinstance(self.symmetry_share, int | float) and 0.0 <= self.symmetry_share
                and self.pivot_share + self.slide_share + self.symmetry_share <= 1.0 + 1e-9):
            raise ValueError(f"LearnParams.symmetry_share must lie in [0, 1 - pivot_share - "
                             f"slide_share], got {self.symmetry_share!r}")
        if self.symmetry != "auto":
            try:
                Symmetry.parse(self.symmetry)
            except ValueError as e:
                raise ValueError(f"LearnParams.{e}") from None
        for name in ("axis_angle", "pivot_angle", "slide_distance"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"LearnParams.{name} must be finite and > 0, got {value!r}")
        for name in ("robust_position_sd", "robust_angle_sd", "slip_scale"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LearnParams.{name} must be finite and >= 0, got {value!r}")
        if self.subsample_size > self.sketch_size:
            raise ValueError(
                f"LearnParams.subsample_size ({self.subsample_size}) must not exceed "
                f"sketch_size ({self.sketch_size}): Kameleon draws its subsample from the sketch"
            )

    def kameleon_scales(self, sketch) -> tuple[float, float]:
        """``(sigma, nu)`` handed to the sampler for this sketch (see ``nu_convention``)."""
        sigma = self.kernel_sigma if self.kernel_sigma is not None else median_heuristic(sketch)
        if self.nu_convention == "literal":
            return float(sigma), float(self.nu)
        return float(sigma), float(self.nu * sigma**2 / (2.0 * math.sqrt(self.subsample_size)))

    @classmethod
    def paper(cls, **changes) -> "LearnParams":
        """The paper's Table I settings (raw coordinates, fixed scales, sketch-covariance
        regions mapped centre to centre, the epsilon density), with ``changes``."""
        table_i = {"gamma": 1e-4, "nu": 2.38 / math.sqrt(6.0), "p_check": 0.6, "epsilon": 0.7,
                   "kernel_sigma": None, "length_scale": 1.0, "target_acceptance": None,
                   "region_scale": None, "uniform_jumps": False, "slip_weight": 1.0,
                   "epsilon_power": 1.0, "axis_moves": 0.0, "pivot_share": 0.0,
                   "slide_share": 0.0, "symmetry_share": 0.0, "robust_tries": 0, "slip_scale": 0.0,
                   "density_floor": 1e-4}
        return cls(**{**table_i, **changes})

    @property
    def num_steps(self) -> int:
        """Proposals per chain: burn-in plus iterations (1100 with Table I)."""
        return self.burn_in + self.iterations

    @property
    def trials_per_proposal(self) -> int:
        """Physics trials one proposal costs: the grasp and its perturbed tries."""
        return 1 + self.robust_tries

    def density_options(self) -> dict:
        """The target-density arguments of ``jg.density.grasp_logdensity`` these params set."""
        return {"floor": self.density_floor, "slip_weight": self.slip_weight,
                "power": self.epsilon_power, "tries": self.robust_tries,
                "position_sd": self.robust_position_sd, "angle_sd": self.robust_angle_sd,
                "estimate": self.robust_estimate, "slip_scale": self.slip_scale}

    def replace(self, **changes) -> "LearnParams":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "LearnParams":
        """Inverse of :meth:`to_dict`; unknown keys are an error (a file from another version)."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown LearnParams fields {sorted(unknown)}")
        return cls(**data)


def _check_int(name, value, *, minimum):
    if not isinstance(value, int) or isinstance(value, bool):
        raise ValueError(f"LearnParams.{name} must be an int, got {value!r}")
    if value < minimum:
        raise ValueError(f"LearnParams.{name} must be >= {minimum}, got {value}")
