"""Regenerate the shipped objects: ``python -m jaxgrasp.objects.generate`` (``make assets``).

Writes ``assets/objects/<name>.npz`` (uncompressed zip with fixed timestamps, so the bytes only
depend on the geometry), ``assets/manifest.json`` and, unless ``--no-renders``,
``assets/renders/<name>.png`` (mesh, convex pieces, cross-section on the table). Geometry and
manifest are bit-for-bit reproducible (libm trig, fixed zip metadata, floats printed with 9
significant digits); renders depend on fonts and are not part of the check.
"""

import argparse
import hashlib
import io
import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import trimesh

from jaxgrasp.objects import decompose, kitchen, render, shipped

FORMAT_VERSION = 1
COVERAGE_SAMPLES = 20000


def _g(x: float) -> float:
    """Round to 9 significant digits: the manifest must not change with last-bit noise."""
    x = float(f"{float(x):.9g}")
    return 0.0 if abs(x) < 1e-12 else x  # -7e-18 is a rounding artefact of an exact 0


def write_npz(path, arrays: dict) -> bytes:
    """An .npz readable by ``np.load`` whose bytes depend only on the arrays."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            data = io.BytesIO()
            np.lib.format.write_array(data, np.ascontiguousarray(value), allow_pickle=False)
            zf.writestr(info, data.getvalue())
    raw = buf.getvalue()
    Path(path).write_bytes(raw)
    return raw


def coverage(spec, built, mesh) -> dict:
    """Measured deviation of the pieces from the solid (metres), both directions.

    ``surface_to_pieces``: largest distance of a surface sample to the union of the pieces
    (holes in the collision geometry). ``pieces_to_solid``: largest distance of a sample on a
    revolved piece's boundary to the solid of revolution (bulges); handle pieces are exact.
    """
    points, _ = trimesh.sample.sample_surface(mesh, COVERAGE_SAMPLES, seed=0)
    gap = decompose.distance_to_pieces(points, built.pieces)
    rng = np.random.default_rng(0)
    body = [p.astype(float) for p in built.pieces[: built.body_pieces]]
    on_pieces = decompose.sample_hull_surfaces(body, 2000, rng)
    bulge = decompose.distance_outside_profile(on_pieces, spec.profile)
    return {"surface_to_pieces": float(gap.max()), "pieces_to_solid": float(bulge.max())}


def build_entry(spec, built) -> tuple[dict, dict]:
    """(manifest entry without the file hash, arrays to store) for one built object."""
    mesh = trimesh.Trimesh(built.vertices.astype(float), built.faces, process=False)
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError(f"{spec.name}: generated mesh is not a watertight positive solid")
    mesh.density = spec.density
    com = np.asarray(mesh.center_mass)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in built.pieces])]).astype(np.int32)
    arrays = {
        "vertices": built.vertices.astype(np.float32),
        "faces": built.faces.astype(np.int32),
        "piece_vertices": np.concatenate(built.pieces).astype(np.float32),
        "piece_offsets": offsets,
    }
    lo, hi = mesh.bounds
    dims = {k: _g(v) for k, v in spec.dimensions.items()}
    dims.update(length_x=_g(hi[0] - lo[0]), width_y=_g(hi[1] - lo[1]))
    cov = coverage(spec, built, mesh)
    entry = {
        "name": spec.name,
        "set": spec.set,
        "kind": spec.kind,
        "description": spec.description,
        "material": spec.material,
        "density": spec.density,
        "dimensions": dims,
        "volume": _g(mesh.volume),
        "mass": _g(mesh.mass),
        "com": [_g(x) for x in com],
        "inertia": [[_g(x) for x in row] for row in np.asarray(mesh.moment_inertia)],
        "support_z": _g(lo[2]),
        "max_radius": _g(np.linalg.norm(mesh.vertices - com, axis=1).max()),
        "num_pieces": len(built.pieces),
        "piece_vertices": [len(p) for p in built.pieces],
        "body_pieces": built.body_pieces,
        "coverage_mm": {k: round(v * 1e3, 3) for k, v in cov.items()},
        "mesh_vertices": len(built.vertices),
        "mesh_faces": len(built.faces),
    }
    return entry, arrays


def generate(out_dir=None, *, renders: bool = True, verbose: bool = True) -> dict:
    """Build every shipped object into ``out_dir`` (default: the repository's assets/)."""
    out = Path(out_dir or shipped.ASSETS_DIR)
    (out / "objects").mkdir(parents=True, exist_ok=True)
    specs = kitchen.specs()
    entries = {}
    for name in shipped.names():
        spec = specs[name]
        built = kitchen.build(spec)
        entry, arrays = build_entry(spec, built)
        rel = f"objects/{name}.npz"
        raw = write_npz(out / rel, arrays)
        entry["file"] = rel
        entry["sha256"] = hashlib.sha256(raw).hexdigest()
        entries[name] = entry
        if verbose:
            print(f"{name:13s} {entry['mass']:.3f} kg  {entry['num_pieces']:2d} pieces  "
                  f"coverage {entry['coverage_mm']}", file=sys.stderr)
    manifest = {
        "format_version": FORMAT_VERSION,
        "generator": "python -m jaxgrasp.objects.generate",
        "units": {"length": "m", "mass": "kg", "density": "kg/m^3", "inertia": "kg m^2"},
        "frame": "base on z = 0, revolution axis z, handle along +x; inertia about the com",
        "sets": {k: list(v) for k, v in shipped.SETS.items()},
        "objects": entries,
    }
    (out / shipped.MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    if renders:
        (out / "renders").mkdir(exist_ok=True)
        for name in shipped.names():
            vertices, faces, pieces = shipped.read_geometry(out / entries[name]["file"])
            render.render(vertices, faces, pieces, out / "renders" / f"{name}.png", title=name,
                          profile=specs[name].profile, dimensions=entries[name]["dimensions"])
    return manifest


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="output folder (default: assets/)")
    parser.add_argument("--no-renders", action="store_true", help="skip the PNG renders")
    args = parser.parse_args(argv)
    generate(args.out, renders=not args.no_renders)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
