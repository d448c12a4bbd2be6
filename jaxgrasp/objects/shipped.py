"""The shipped kitchen objects: read from ``assets/`` (no regeneration at load time).

``assets/manifest.json`` lists every object with its set, kind, dimensions, mass properties and
the sha256 of its geometry file ``assets/objects/<name>.npz`` (arrays ``vertices`` (V, 3) f4,
``faces`` (F, 3) i4, ``piece_vertices`` (sum V_i, 3) f4, ``piece_offsets`` (P + 1,) i4).
``python -m jaxgrasp.objects.generate`` (``make assets``) rebuilds them bit-for-bit.
"""

import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np
import trimesh

from jaxgrasp.objects.base import GraspObject

# jaxgrasp/assets: a link to the repository's assets/ in a checkout, a copy in a wheel.
ASSETS_DIR = Path(__file__).resolve().parents[1] / "assets"
MANIFEST = "manifest.json"

ACTIVE = ("pitcher", "pan", "plate")
TRANSFER_A = ("tall_pitcher", "saucepan", "soup_plate")
TRANSFER_B = ("small_jug", "frying_pan", "platter")
SETS = {"active": ACTIVE, "transfer_a": TRANSFER_A, "transfer_b": TRANSFER_B}
_KIND = {n: k for k, *rest in zip(("pitcher", "pan", "plate"), ACTIVE, TRANSFER_A, TRANSFER_B,
                                   strict=True)
         for n in (k, *rest)}


def assets_dir() -> Path:
    """Where the shipped assets live (``$JAXGRASP_ASSETS`` overrides, e.g. for tests)."""
    return Path(os.environ.get("JAXGRASP_ASSETS", ASSETS_DIR))


def names(set: str | None = None) -> tuple:  # noqa: A002 - the paper's word
    """Names of the shipped objects: all 9, or those of one set (active/transfer_a/transfer_b)."""
    if set is None:
        return ACTIVE + TRANSFER_A + TRANSFER_B
    if set not in SETS:
        raise ValueError(f"unknown object set {set!r}; expected one of {sorted(SETS)}")
    return SETS[set]


def similar(name: str) -> str:
    """The active-set object of the same kind (tall_pitcher -> pitcher, platter -> plate)."""
    if name not in _KIND:
        raise ValueError(f"unknown object {name!r}; shipped objects are {names()}")
    return _KIND[name]


def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@functools.lru_cache(maxsize=4)
def _manifest(directory: str) -> dict:
    path = Path(directory) / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: run `make assets` to generate the objects")
    return json.loads(path.read_text())


def manifest(directory=None) -> dict:
    """The parsed manifest: {"objects": {name: entry}, ...}."""
    return _manifest(str(directory or assets_dir()))


def read_geometry(path) -> tuple:
    """(vertices (V,3) f8, faces (F,3) i8, pieces tuple of (V_i,3) f8) from an object file."""
    with np.load(path) as z:
        vertices = z["vertices"].astype(np.float64)
        faces = z["faces"].astype(np.int64)
        pv = z["piece_vertices"].astype(np.float64)
        off = z["piece_offsets"]
    pieces = tuple(pv[off[i] : off[i + 1]] for i in range(len(off) - 1))
    return vertices, faces, pieces


@functools.lru_cache(maxsize=32)
def _load(name: str, directory: str) -> GraspObject:
    entry = manifest(directory)["objects"][name]
    vertices, faces, pieces = read_geometry(Path(directory) / entry["file"])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.density = entry["density"]
    for p in pieces:
        p.setflags(write=False)
    return GraspObject(
        name=name,
        mesh=mesh,
        pieces=pieces,
        mass=float(entry["mass"]),
        com=np.asarray(entry["com"], dtype=float),
        inertia=np.asarray(entry["inertia"], dtype=float),
        support_z=float(entry["support_z"]),
        max_radius=float(entry["max_radius"]),
        kind=entry["kind"],
        set=entry["set"],
        content_hash=entry["sha256"],
        dimensions=dict(entry["dimensions"]),
    )


def load(name: str) -> GraspObject:
    """A shipped object by name (see :func:`names`), read from the committed assets.

    The result is cached and shared: don't mutate its mesh.
    """
    if name not in names():
        raise ValueError(f"unknown object {name!r}; shipped objects are {names()}")
    return _load(name, str(assets_dir()))
