"""The learning flags of ``python -m jaxgrasp.learn``, for one object and a dataset alike: the
sampler (``jg.learn.active``'s ``method``) and the :class:`LearnParams` fields of its target.

``--learn-tries``, ``--slip-scale`` and ``--robust-estimate`` are thin aliases of
``--param robust_tries=K`` etc.; ``--param`` sets any other field. A run records the fields
that differ from the defaults (:func:`learn_params`), so a resume with other values is caught.
"""

import argparse
import dataclasses
import math

from jaxgrasp.density import ESTIMATES
from jaxgrasp.learn.active_learning import ACTIVE_METHODS
from jaxgrasp.learn.params import LearnParams

__all__ = ["ALIASES", "FLOOD", "RECIPE_FLAGS", "Given", "add_arguments", "choose_recipe",
           "grow_budget", "integer", "learn_params", "passed_on", "recipe_given"]

_FIELDS = {f.name: f for f in dataclasses.fields(LearnParams)}
#: Fields with their own flag (not settable by ``--param``).
_OWN_FLAG = {"iterations": "--iterations", "burn_in": "--burn-in"}
#: ``(args attribute, flag, LearnParams field)`` of the aliases.
ALIASES = (("learn_tries", "--learn-tries", "robust_tries"),
           ("slip_scale", "--slip-scale", "slip_scale"),
           ("robust_estimate", "--robust-estimate", "robust_estimate"))


#: The flags of a recipe (``args`` attributes): the learn CLI chooses them where none is given.
RECIPE_FLAGS = ("iterations", "burn_in", "sketch", "grow_every")
#: The recipe where the object has no axis of revolution: a short run with the random sketch
#: (no trial), then a flood from every success (``grow_every``: per 8 chains, about the trials
#: the parser's defaults would spend on 1100 proposals per chain and the biased sketch).
FLOOD = {"iterations": 100, "burn_in": 10, "sketch": "random", "grow_every": 8750}


class Given(argparse.Action):
    """Stores a flag's value and notes that it was given (``args.given``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        namespace.given = getattr(namespace, "given", frozenset()) | {self.dest}


def recipe_given(args) -> bool:
    """Whether a flag of the recipe was given (then the parser's defaults fill the others)."""
    return bool(set(getattr(args, "given", ())) & set(RECIPE_FLAGS))


def choose_recipe(args, symmetry) -> str:
    """``"flood"`` (and ``args`` set to :data:`FLOOD`) where Kameleon + GDMC learns an object
    whose ``symmetry`` (its :class:`~jaxgrasp.objects.Symmetry`) is no revolution and no flag
    of the recipe was given, else ``"chains"`` (``args`` as parsed): on a mesh the flood finds
    more distinct grasps and more robust ones; on a solid of revolution the chains' turns and
    ``--grow`` keep more robust ones."""
    if (recipe_given(args) or args.method != "kameleon_darting"
            or symmetry.kind == "revolution"):
        return "chains"
    for name, value in {**FLOOD, "grow_every": FLOOD["grow_every"] * args.chains // 8}.items():
        setattr(args, name, value)
    return "flood"


def integer(minimum: int):
    """An argparse type: an integer >= ``minimum`` (the message says "positive" for 1)."""
    wanted = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {value}")
        return value

    return parse


def _metres(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected metres (a number), got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected finite metres >= 0, got {text!r}")
    return value


def _value(name: str, text: str):
    """``text`` as a value of field ``name``: none, true/false, an int, a float, else text."""
    low = text.strip().lower()
    if low in ("none", "null"):
        return None
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            value = kind(text)
        except ValueError:
            continue
        # a float field given "1" records 1.0, as its default is written
        return float(value) if isinstance(_FIELDS[name].default, float) else value
    return text


def _param(text: str) -> tuple:
    """``NAME=VALUE`` of ``--param``: ``(name, value)``; a bad form or name ends the parser."""
    name, sep, raw = text.partition("=")
    name = name.strip()
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    if name in _OWN_FLAG:
        raise argparse.ArgumentTypeError(f"{name}: use {_OWN_FLAG[name]}")
    if name not in _FIELDS:
        raise argparse.ArgumentTypeError(
            f"{name!r} is no LearnParams field; fields: "
            f"{', '.join(n for n in _FIELDS if n not in _OWN_FLAG)}")
    return name, _value(name, raw)


def add_arguments(p) -> None:
    """The learning flags of ``python -m jaxgrasp.learn``."""
    g = p.add_argument_group("learning: the sampler and its target (a dataset passes these on "
                             "to every object)")
    g.add_argument("--method", choices=ACTIVE_METHODS, default="kameleon_darting",
                   help="kameleon_darting: Kameleon MCMC + GDMC jumps between the demos; "
                        "random_walk: a Gaussian/von Mises-Fisher walk from the demos; "
                        "antipodal: chains x (burn-in + iterations) collision-free antipodal "
                        "grasps, each simulated once (no demos needed; no mid-run checkpoint: "
                        "an interrupted one starts over) (default: %(default)s)")
    g.add_argument("--learn-tries", type=integer(0), metavar="K",
                   help="while learning, simulate each proposal K more times under a pose "
                        "error (LearnParams.robust_tries; the error: --param "
                        "robust_position_sd=M, robust_angle_sd=DEG, default 3 mm, 3 deg, not "
                        "--pose-error) and sample the quality smoothed over it, so the chains "
                        "seek grasps that hold when the robot misses a bit; each proposal "
                        "costs K + 1 trials (default 0). Not --robust-tries, the tries that "
                        "score the learned grasps afterwards")
    g.add_argument("--slip-scale", type=_metres, metavar="METRES",
                   help="weigh each grasp by exp(-displacement / METRES), the object's largest "
                        "slip in the gripper during the hold (LearnParams.slip_scale; 0: the "
                        f"paper's density; default {LearnParams.slip_scale})")
    g.add_argument("--robust-estimate", choices=ESTIMATES,
                   help="what the --learn-tries estimate: the quality smoothed over the pose "
                        "error (mean) or the quality times the chance that every try holds "
                        "(all_held) (LearnParams.robust_estimate; default mean)")
    g.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="set any LearnParams field (repeatable; docs: jaxgrasp/learn/params.py),"
                        " e.g. --param gamma=0.02 --param region_scale=none; values: numbers, "
                        "true/false, none or text")


def _given(args) -> dict:
    """``{field: (flag text, value)}`` the command line sets; a field set twice is an error."""
    given = {}
    sets = [(f"{flag} {getattr(args, attr)}", field, getattr(args, attr))
            for attr, flag, field in ALIASES if getattr(args, attr) is not None]
    sets += [(f"--param {name}={value}", name, value) for name, value in args.param]
    for text, field, value in sets:
        if field in given:
            raise ValueError(f"{given[field][0]} and {text} both set LearnParams.{field}")
        given[field] = (text, value)
    return given


def learn_params(args) -> tuple:
    """``(LearnParams, record)`` of the parsed command line; ``record`` is the fields that
    differ from the defaults (``iterations`` and ``burn_in`` aside), what a run records.

    Raises
    ------
    ValueError
        A bad value (the message names the flag), a field set twice, or a field the
        antipodal sampler does not read.
    """
    given = _given(args)
    if args.method == "antipodal" and given:
        raise ValueError(f"--method antipodal reads only --iterations and --burn-in (it "
                         f"simulates chains x (burn-in + iterations) grasps once each), not "
                         f"{', '.join(text for text, _ in given.values())}")
    try:
        params = LearnParams(iterations=args.iterations, burn_in=args.burn_in,
                             **{field: value for field, (_, value) in given.items()})
    except (TypeError, ValueError) as err:
        message = str(err)
        for field, (text, _) in given.items():
            message = message.replace(f"LearnParams.{field}", f"{text}: LearnParams.{field}")
        raise ValueError(message) from None
    default = LearnParams().to_dict()
    record = {k: v for k, v in params.to_dict().items()
              if k not in _OWN_FLAG and v != default[k]}
    return params, record


def passed_on(args) -> list:
    """The learning flags as command-line words, for each object of a dataset."""
    words = ["--method", args.method]
    for attr, flag, _ in ALIASES:
        if getattr(args, attr) is not None:
            words += [flag, str(getattr(args, attr))]
    for name, value in args.param:
        words += ["--param", f"{name}={'none' if value is None else value}"]
    return words


def grow_budget(args) -> int | None:
    """``--grow``'s trials: as given, else as many as the chains' proposals where the grasps
    are scored (``--robust-tries`` > 0), else 0; None before the recipe is chosen (a dataset's
    objects each choose theirs)."""
    if getattr(args, "grow", None) is not None:
        return int(args.grow)
    if not hasattr(args, "recipe") and not recipe_given(args):
        return None
    return args.chains * (args.burn_in + args.iterations) if args.robust_tries else 0
