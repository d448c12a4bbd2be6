"""The any-object evaluation set: 24 of pybullet's random objects, shipped, never downloaded.

``assets/any_object/`` holds 24 meshes of ``pybullet_data/random_urdfs`` (pybullet 3.2.7,
zlib licence; ``SOURCE.md`` credits them), byte for byte as in the wheel, and
``manifest.json``: per object the pybullet id, the mesh scale of its URDF, the file's sha256,
its extents, solidity (volume / convex-hull volume) and shape class. Nobody here made these
shapes: they test grasping on objects that are not solids of revolution.

``python -m jaxgrasp.objects.any_object --wheel pybullet-3.2.7-....whl`` redraws the set:
``numpy.random.default_rng(0).permutation(1000)`` orders the ids and the first 24 that
:func:`jaxgrasp.objects.from_mesh` loads (no error, no warning) at their URDF scale with at
least :data:`MIN_VOLUME` of material are kept.
"""

import argparse
import hashlib
import json
import re
import shutil
import sys
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from jaxgrasp.objects.base import GraspObject
from jaxgrasp.objects.shipped import assets_dir
from jaxgrasp.objects.user import from_mesh

__all__ = ["PREFIX", "any_object_set", "load", "names", "shape_class"]

SET = "any_object"
PREFIX = "random_"
#: Objects in the set and the seed of the draw over pybullet's 1000 random ids.
SET_SIZE = 24
DRAW_SEED = 0
#: Below 1 cm^3 a random object is a wire frame (id 350: 0.2 cm^3), not a solid to hold.
MIN_VOLUME = 1e-6
#: Shape classes from the sorted bounding-box extents a <= b <= c and the solidity.
FLAT_RATIO = 0.5  # a / b below this: a slab
ELONGATED_RATIO = 0.5  # b / c below this: a bar
CONCAVE_SOLIDITY = 0.5  # volume / hull volume below this: more hollow than solid


def set_dir() -> Path:
    """``assets/any_object`` (under ``$JAXGRASP_ASSETS`` when set)."""
    return assets_dir() / SET


def _manifest() -> dict:
    path = set_dir() / "manifest.json"
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: the any-object set is not installed")
    return json.loads(path.read_text())


def names() -> tuple:
    """Names of the set's objects (``random_NNN``, NNN the pybullet id), in draw order."""
    return tuple(_manifest()["objects"])


def any_object_set() -> dict:
    """``{name: {"path": Path of the .obj, "scale": URDF mesh scale, "shape": class, ...}}``
    of the 24 objects, in draw order (the manifest's entries with the file's full path)."""
    root = set_dir()
    return {n: {**e, "path": root / e["file"]} for n, e in _manifest()["objects"].items()}


def load(name: str) -> GraspObject:
    """One object of the set as a GraspObject (:func:`~jaxgrasp.objects.from_mesh` at its URDF
    scale; CoACD decomposes it on first use, then the user-mesh cache serves it)."""
    entries = any_object_set()
    if name not in entries:
        raise ValueError(f"unknown any-object {name!r}; the set is {tuple(entries)}")
    e = entries[name]
    # Same geometry as from_mesh's, but the record says which set it comes from.
    return replace(from_mesh(e["path"], scale=e["scale"], name=name), set=SET)


def shape_class(extents, solidity: float) -> str:
    """``"flat"``, ``"elongated"``, ``"flat, elongated"`` or ``"round"`` from the bounding
    box, with ``", concave"`` added below :data:`CONCAVE_SOLIDITY`."""
    a, b, c = np.sort(np.asarray(extents, float))
    parts = [k for k, hit in (("flat", a / b < FLAT_RATIO), ("elongated",
                                                              b / c < ELONGATED_RATIO)) if hit]
    label = ", ".join(parts) or "round"
    return label + (", concave" if solidity < CONCAVE_SOLIDITY else "")


# ------------------------------------------------------------------------- redrawing the set
def _urdf_scale(text: str) -> float:
    m = re.search(r'<mesh[^>]*scale="([^"]+)"', text)
    scales = [float(s) for s in m.group(1).split()] if m else [1.0]
    if len(set(scales)) != 1:
        raise ValueError(f"non-uniform mesh scale {scales}")
    return scales[0]


def draw(wheel, out: Path, *, count: int = SET_SIZE, seed: int = DRAW_SEED) -> dict:
    """Draw the set from a pybullet wheel (a zip) into ``out``; returns the manifest."""
    out.mkdir(parents=True, exist_ok=True)
    root = "pybullet_data/random_urdfs"
    entries = {}
    tmp = out / ".draw"
    with zipfile.ZipFile(wheel) as z:
        licence = z.read("pybullet-3.2.7.dist-info/LICENSE.txt").decode()
        for i in np.random.default_rng(seed).permutation(1000):
            if len(entries) == count:
                break
            pid = f"{int(i):03d}"
            tmp.mkdir(exist_ok=True)
            obj_path = tmp / f"{pid}.obj"
            obj_path.write_bytes(z.read(f"{root}/{pid}/{pid}.obj"))
            scale = _urdf_scale(z.read(f"{root}/{pid}/{pid}.urdf").decode())
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error")
                    obj = from_mesh(obj_path, scale=scale, name=PREFIX + pid)
            except (ValueError, UserWarning) as e:
                print(f"{pid}: skipped ({e})", flush=True)
                continue
            volume = float(obj.mesh.volume)
            if volume < MIN_VOLUME:
                print(f"{pid}: skipped ({volume * 1e6:.2g} cm^3 < 1 cm^3)", flush=True)
                continue
            solidity = volume / float(obj.mesh.convex_hull.volume)
            extents = [float(x) for x in obj.mesh.extents]
            shutil.copyfile(obj_path, out / f"{pid}.obj")
            entries[PREFIX + pid] = {
                "id": pid, "file": f"{pid}.obj", "scale": scale,
                "sha256": hashlib.sha256(obj_path.read_bytes()).hexdigest(),
                "extents_mm": [round(1e3 * x, 1) for x in extents],
                "volume_cm3": round(volume * 1e6, 2), "solidity": round(solidity, 3),
                "pieces": len(obj.pieces), "shape": shape_class(extents, solidity)}
            print(f"{pid}: {entries[PREFIX + pid]['shape']}", flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    manifest = {"source": "pybullet 3.2.7 wheel, pybullet_data/random_urdfs (zlib licence)",
                "draw": f"numpy.random.default_rng({seed}).permutation(1000), the first "
                        f"{count} ids that jg.objects.from_mesh loads at their URDF scale "
                        "without error or warning, with at least 1 cm^3 of material",
                "objects": entries}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    (out / "LICENSE.txt").write_text(licence)
    return manifest


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Redraw the any-object set from a pybullet wheel")
    p.add_argument("--wheel", required=True, help="pybullet-3.2.7-*.whl (read as a zip)")
    p.add_argument("--out", type=Path, default=None, help="default: assets/any_object")
    args = p.parse_args(argv)
    draw(args.wheel, args.out or set_dir())
    return 0


if __name__ == "__main__":
    sys.exit(main())
