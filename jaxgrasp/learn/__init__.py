"""Learning workflows: demonstrations, rough sketches, active and transfer learning, chain files.

>>> demos = jg.learn.demonstrations(obj, num=5, seed=0)
>>> res = jg.learn.active(obj, method="kameleon_darting", sketch="biased", chains=4, seed=0)
>>> res.save("runs/pitcher"); res = jg.learn.load("runs/pitcher", obj)
>>> new = jg.learn.transfer(res, "tall_pitcher", modes="source", size_aware=True)
>>> jg.learn.export_grasps(res, "pitcher.h5"); tree = res.to_arviz()
"""

from jaxgrasp.learn.active_learning import active
from jaxgrasp.learn.algorithm import make_algorithm
from jaxgrasp.learn.chains import run_chains
from jaxgrasp.learn.cohort import Cohort
from jaxgrasp.learn.evaluate import distinct
from jaxgrasp.learn.evaluate.distinct import learned_grasps, unique_grasps
from jaxgrasp.learn.evaluate.grow import grow
from jaxgrasp.learn.evaluate.robustness import PoseNoise, Robustness, grow_robust, robustness
from jaxgrasp.learn.files.export import GraspSet, export_grasps, load_grasps
from jaxgrasp.learn.files.results import OUTCOME_NAMES, LearnResult, load, outcome_counts
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.setup.candidates import candidate_poses
from jaxgrasp.learn.setup.demos import Demos, demonstrations
from jaxgrasp.learn.setup.resize import SizeMap
from jaxgrasp.learn.setup.sketch import biased_sketch, random_sketch
from jaxgrasp.learn.sim import Simulator
from jaxgrasp.learn.transfer_learning import transfer

__all__ = [
    "OUTCOME_NAMES",
    "Cohort",
    "Demos",
    "GraspSet",
    "LearnParams",
    "LearnResult",
    "PoseNoise",
    "Robustness",
    "Simulator",
    "SizeMap",
    "active",
    "biased_sketch",
    "build_atlas",
    "candidate_poses",
    "demonstrations",
    "distinct",
    "export_grasps",
    "grow",
    "grow_robust",
    "learned_grasps",
    "outcome_counts",
    "load",
    "load_grasps",
    "load_atlas",
    "make_algorithm",
    "random_sketch",
    "robustness",
    "run_chains",
    "transfer",
    "unique_grasps",
]


def __getattr__(name):
    if name in ("build_atlas", "load_atlas"):
        # why: loaded on use, so `python -m jaxgrasp.learn.evaluate.atlas` runs a fresh module
        from jaxgrasp.learn.evaluate import atlas

        return getattr(atlas, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
