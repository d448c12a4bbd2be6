"""An object's symmetry about a vertical axis, found from its mesh.

A grasp trial has gravity along -z and a table under the object, so the only turns that map a
grasp to an equivalent one are turns about a vertical axis; mirror planes that keep the task are
vertical too. :func:`find_symmetry` tests, for a few candidate axes ``(cx, cy)`` (the object
frame's origin, the centre of mass, the bounding-box centre and each refined to fit the
surface), whether the surface maps onto itself turned about that axis:

- ``"revolution"``: every turn (four turns at angles that no n-fold symmetry with n <= 12
  shares, 17°, 53°, 101° and 163°);
- ``"turns"`` of ``order`` n: the turns by ``2πk/n`` (the largest n in 2..8 that passes);
- ``"none"``.

A turn passes when at least ``share`` of the surface samples land within ``tol`` of the surface
(a handle covers a few percent of a pitcher: its body still counts as a solid of revolution).
Vertical mirror planes through the axis are recorded too (``mirrors``: plane angles in degrees).
Numpy, scipy and trimesh only; about a second per object.
"""

import math
from dataclasses import asdict, dataclass

import numpy as np
import trimesh

__all__ = ["Symmetry", "KINDS", "find_symmetry", "same_surroundings"]

KINDS = ("revolution", "turns", "none")
#: Turn angles (degrees) a solid of revolution must pass; no n-fold symmetry (n <= 12) has them all.
REVOLUTION_TEST = (17.0, 53.0, 101.0, 163.0)
#: Orders tested for n-fold turns, largest first.
ORDERS = (8, 6, 5, 4, 3, 2)
#: Share of surface samples that must map onto the surface.
SHARE = 0.9
#: Surface samples; their spacing sets the distance that counts as on the surface, so a
#: symmetry is tested locally (:func:`same_surroundings`) as it was found.
SAMPLES = 2000
#: Surface samples the centre refinement maps (the classification uses all).
REFINE_SAMPLES = 500
#: Share of best-matching samples whose mean distance the centre refinement minimises.
TRIM = 0.8


@dataclass(frozen=True)
class Symmetry:
    """Symmetry of an object about the vertical axis through ``centre`` (object frame, metres).

    ``kind`` is ``"revolution"`` (any turn), ``"turns"`` (turns by multiples of 360°/``order``)
    or ``"none"``; ``mirrors`` lists vertical mirror planes through the axis (their angles to
    the x axis, degrees); ``match`` is the smallest share of surface samples the kind's turns
    mapped onto the surface (1.0 for a user's override).
    """

    kind: str = "none"
    centre: tuple = (0.0, 0.0)
    order: int = 1
    mirrors: tuple = ()
    match: float = 1.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"symmetry kind must be one of {KINDS}, got {self.kind!r}")
        if len(self.centre) != 2 or not all(math.isfinite(float(c)) for c in self.centre):
            raise ValueError(f"symmetry centre must be two finite numbers, got {self.centre!r}")
        if self.kind == "turns" and not (isinstance(self.order, int) and self.order >= 2):
            raise ValueError(f"symmetry 'turns' needs an integer order >= 2, got {self.order!r}")

    @classmethod
    def parse(cls, text: str) -> "Symmetry":
        """A user's override: ``none``, ``revolution`` or ``turns:N``, each optionally
        ``@X,Y`` (the axis through ``(X, Y)`` metres; default the object frame's z axis)."""
        spec, _, at = str(text).strip().partition("@")
        try:
            centre = tuple(float(v) for v in at.split(",")) if at else (0.0, 0.0)
            kind, _, order = spec.partition(":")
            if kind == "turns":
                return cls("turns", centre, int(order))
            if order or kind not in ("none", "revolution"):
                raise ValueError(spec)
            return cls(kind, centre, 0 if kind == "revolution" else 1)
        except ValueError:
            raise ValueError(f"symmetry must be 'auto', 'none', 'revolution' or 'turns:N', "
                             f"optionally '@X,Y' (the vertical axis through X, Y metres); "
                             f"got {text!r}") from None

    @property
    def trivial(self) -> bool:
        """No turn and no mirror plane: nothing maps a grasp to an equivalent one."""
        return self.kind == "none" and not self.mirrors

    def to_dict(self) -> dict:
        return {**asdict(self), "centre": [float(c) for c in self.centre],
                "mirrors": [float(m) for m in self.mirrors]}

    @classmethod
    def from_dict(cls, data: dict) -> "Symmetry":
        return cls(data["kind"], tuple(data["centre"]), int(data["order"]),
                   tuple(data.get("mirrors", ())), float(data.get("match", 1.0)))

    def describe(self) -> str:
        at = f"the vertical axis through ({1e3 * self.centre[0]:.1f}, " \
             f"{1e3 * self.centre[1]:.1f}) mm"
        if self.kind == "revolution":
            return f"a solid of revolution about {at}"
        if self.kind == "turns":
            return f"{self.order}-fold turns about {at}"
        return "no turn symmetry"


def _turn(points, centre, angle):
    c, s = math.cos(angle), math.sin(angle)
    xy = points[:, :2] - centre
    out = points.copy()
    out[:, 0] = centre[0] + c * xy[:, 0] - s * xy[:, 1]
    out[:, 1] = centre[1] + s * xy[:, 0] + c * xy[:, 1]
    return out


def _mirror(points, centre, angle):
    """Reflect through the vertical plane through ``centre`` at ``angle`` to the x axis."""
    n = np.array([-math.sin(angle), math.cos(angle)])
    xy = points[:, :2] - centre
    out = points.copy()
    out[:, :2] = centre + xy - 2.0 * (xy @ n)[:, None] * n
    return out


class _Surface:
    """Surface samples and a KD-tree of a denser sampling: how well a map keeps the surface."""

    def __init__(self, mesh, samples: int, seed: int):
        from scipy.spatial import cKDTree  # scipy loads only when a symmetry is looked for

        rng = np.random.default_rng(seed)
        self.points = np.asarray(trimesh.sample.sample_surface(mesh, samples, seed=rng)[0], float)
        ref = np.asarray(trimesh.sample.sample_surface(mesh, 10 * samples, seed=rng)[0], float)
        self.tree = cKDTree(ref)
        # Distances of true surface points to the reference set: the sampling's own noise.
        own = self.tree.query(self.points)[0]
        size = float(np.linalg.norm(mesh.extents))
        self.tol = max(2.0 * float(np.quantile(own, 0.95)), 0.005 * size)

    def match(self, mapped) -> float:
        # a bounded search: far points stop early (returned as inf)
        return float(np.mean(self.tree.query(mapped, distance_upper_bound=self.tol)[0]
                             < self.tol))

    def trimmed(self, mapped) -> float:
        cap = 10.0 * self.tol
        d = np.sort(np.minimum(self.tree.query(mapped, distance_upper_bound=cap)[0], cap))
        return float(d[: int(TRIM * len(d))].mean())


def _passes(surface, maps, share):
    """The smallest match of ``maps`` (each ``points -> points``), or None as soon as one
    fails (on a subsample first: most candidate maps fail at once)."""
    worst = 1.0
    for f in maps:
        if surface.match(f(surface.points[:REFINE_SAMPLES])) < share - 0.1:
            return None
        m = surface.match(f(surface.points))
        if m < share:
            return None
        worst = min(worst, m)
    return worst


def _turns(centre, angles):
    return [lambda p, a=a: _turn(p, centre, a) for a in angles]


def _classify(surface, centre, share):
    """``(kind, order, match)`` of the turns about ``centre``."""
    rev = _passes(surface, _turns(centre, np.radians(REVOLUTION_TEST)), share)
    if rev is not None:
        return "revolution", 0, rev
    for n in ORDERS:
        m = _passes(surface, _turns(centre, 2 * np.pi * np.arange(1, n) / n), share)
        if m is not None:
            return "turns", n, m
    return "none", 1, 0.0


def _refine(surface, start):
    """The centre near ``start`` that best maps the surface onto itself by a half or a third
    of a turn (every revolution and n-fold symmetry has one of the two)."""
    from scipy.optimize import minimize  # scipy loads only when a symmetry is looked for

    best = np.asarray(start, float)
    pts = surface.points[:REFINE_SAMPLES]
    for angle in (math.pi, 2 * math.pi / 3):
        res = minimize(lambda c, a=angle: surface.trimmed(_turn(pts, c, a)),
                       np.asarray(start, float), method="Nelder-Mead",
                       options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 200})
        if surface.trimmed(_turn(pts, res.x, angle)) < surface.trimmed(
                _turn(pts, best, angle)):
            best = res.x
    return best


def find_symmetry(obj, *, samples: int = SAMPLES, share: float = SHARE,
                  seed: int = 0) -> Symmetry:
    """The symmetry of ``obj`` (a GraspObject or a trimesh) about a vertical axis.

    Candidate axes, in order: the object frame's z axis, the vertical through the centre of
    mass and through the bounding-box centre, then each refined. The first candidate of the
    richest kind wins (revolution, then the highest order), so an object built about its z
    axis keeps exactly that axis.
    """
    mesh = getattr(obj, "mesh", obj)
    surface = _Surface(mesh, samples, seed)
    starts = [np.zeros(2), np.asarray(mesh.center_mass, float)[:2],
              np.asarray(mesh.bounds, float).mean(axis=0)[:2]]
    best = None  # (rank, kind, order, match, centre); the first of the richest rank wins
    for centre in starts:
        best = _richer(best, surface, centre, share)
    if best[1] != "revolution":  # nothing is richer than a revolution: no refining then
        for centre in starts:
            best = _richer(best, surface, _refine(surface, centre), share)
    _, kind, order, m, centre = best
    centre = starts[1] if kind == "none" else centre
    mirrors = () if kind == "revolution" else _mirrors(surface, centre, share)
    return Symmetry(kind, (float(centre[0]), float(centre[1])), int(order), mirrors, float(m))


def _richer(best, surface, centre, share):
    """``best`` or the classification at ``centre``, whichever is strictly richer."""
    kind, order, m = _classify(surface, centre, share)
    rank = (KINDS[::-1].index(kind), order if kind == "turns" else 0)
    return best if best is not None and rank <= best[0] else (rank, kind, order, m, centre)


def _mirrors(surface, centre, share) -> tuple:
    """Vertical mirror planes through ``centre``: a 1° scan, each run of passing angles
    reported once, at its middle (a solid of revolution has every plane: not listed)."""
    angles = np.arange(180)
    ok = np.array([_passes(surface, [lambda p, a=a: _mirror(p, centre, math.radians(a))],
                           share) is not None for a in angles])
    out = []
    for a in np.flatnonzero(ok & ~np.roll(ok, 1)) if not ok.all() else []:
        run = [a]
        while ok[(run[-1] + 1) % 180] and len(run) < 180:
            run.append((run[-1] + 1) % 180)
        out.append(float(angles[run[len(run) // 2]]))
    return tuple(sorted(out))


def same_surroundings(obj, symmetry: Symmetry, *, radius: float, samples: int = SAMPLES,
                      share: float = SHARE, seed: int = 0):
    """A test ``(centres (n, 3), angles (n,), mirror=None) -> (n,) bool``: whether the object
    looks the same within ``radius`` of each centre and of that centre mapped by the symmetry
    (turned by its angle about ``symmetry``'s axis, or, where ``mirror`` (n,) bool is set,
    reflected through the vertical plane through the axis at that angle): the surface near
    each, mapped onto the other, lands on the surface for at least ``share`` of its samples
    (``samples`` and ``share`` as :func:`find_symmetry` found the symmetry). A
    whole object can be a solid of revolution with a handle: a grasp on the body turns into a
    grasp that holds the same way, one on the handle into air."""
    from scipy.spatial import cKDTree  # scipy loads only when a symmetry is looked for

    mesh = getattr(obj, "mesh", obj)
    surface = _Surface(mesh, samples, seed)
    near = cKDTree(surface.points)
    axis = np.asarray(symmetry.centre, float)

    def test(centres, angles, mirror=None) -> np.ndarray:
        c = np.asarray(centres, float).reshape(-1, 3)
        a = np.asarray(angles, float).reshape(-1)
        m = np.zeros(len(c), bool) if mirror is None else np.asarray(mirror, bool).reshape(-1)
        ok = np.zeros(len(c), bool)
        for i in range(len(c)):
            there, back = ((lambda p, t=a[i]: _mirror(p, axis, t)),) * 2 if m[i] else (
                lambda p, t=a[i]: _turn(p, axis, t), lambda p, t=a[i]: _turn(p, axis, -t))
            to = there(c[i:i + 1])[0]
            ok[i] = all(len(idx := near.query_ball_point(at, radius)) > 0
                        and surface.match(f(surface.points[idx])) >= share
                        for at, f in ((c[i], there), (to, back)))
        return ok

    return test
