"""Chain files: atomic writes, plain-array .npz, checksummed .npz + .json pairs, JSON values.

Every file is written to a temporary name in the same directory and moved into place with
``os.replace``, so a kill never leaves a half-written file under the real name. A pair
``stem.npz`` + ``stem.json`` records the SHA-256 of the array file in the JSON, so a torn pair
(one file from another write) is detected on read.
"""

import hashlib
import io
import json
import os
import platform
import tempfile
import zipfile
import zlib
from pathlib import Path

import jax
import mujoco
import numpy as np

import jaxgrasp

__all__ = ["atomic_write_bytes", "npz_bytes", "read_npz", "write_npz_json", "read_npz_json",
           "jsonable", "versions"]


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory + os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        # A failed write must not leave its temporary file behind.
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def npz_bytes(arrays: dict) -> bytes:
    """Serialize a dict of arrays as an (uncompressed) .npz, refusing object arrays."""
    for key, value in arrays.items():
        if np.asarray(value).dtype == object:
            raise ValueError(f"array {key!r} has dtype object; chain files hold plain arrays only")
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def read_npz(data, label) -> dict:
    """The arrays of an .npz (bytes or path), read with ``allow_pickle=False``.

    ValueError naming ``label`` for anything that is not an intact archive of plain arrays
    (truncated, not a zip, a pickle, object arrays), never an error from inside zipfile.
    """
    source = io.BytesIO(data) if isinstance(data, bytes) else data
    try:
        with np.load(source, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, KeyError, AttributeError, zipfile.BadZipFile,
            zlib.error) as err:
        raise ValueError(f"{label} is not an intact .npz of plain arrays ({type(err).__name__}: "
                         f"{err}); delete it and run again, or restore it") from None


def write_npz_json(directory, stem: str, arrays: dict, meta: dict) -> None:
    """Atomically write ``stem.npz`` then ``stem.json`` (the JSON records the npz's SHA-256).

    Both are serialized before either is written, so a value JSON refuses (NaN/inf in the
    metadata) leaves no file behind.
    """
    directory = Path(directory)
    data = npz_bytes(arrays)
    meta = dict(meta)
    meta["arrays"] = {"file": f"{stem}.npz", "sha256": hashlib.sha256(data).hexdigest()}
    try:
        text = json.dumps(jsonable(meta), indent=1, sort_keys=True, allow_nan=False)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{stem}.json: metadata is not plain JSON ({err}); NaN/inf and "
                         "objects can't be saved") from None
    atomic_write_bytes(directory / f"{stem}.npz", data)
    atomic_write_bytes(directory / f"{stem}.json", text.encode())


def read_npz_json(directory, stem: str) -> tuple[dict, dict]:
    """Read a pair written by :func:`write_npz_json`; ValueError when missing, torn or corrupt."""
    directory = Path(directory)
    meta_path, npz_path = directory / f"{stem}.json", directory / f"{stem}.npz"
    if not meta_path.is_file() or not npz_path.is_file():
        raise ValueError(f"no chain file {stem!r} in {str(directory)!r} (need {stem}.json and "
                         f"{stem}.npz)")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{meta_path} is not valid JSON: {err}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("arrays"), dict):
        raise ValueError(f"{meta_path} is not a jaxgrasp chain file (no 'arrays' record)")
    data = npz_path.read_bytes()
    if meta["arrays"].get("sha256") != hashlib.sha256(data).hexdigest():
        raise ValueError(f"{npz_path} does not match the checksum recorded in {meta_path} "
                         "(the pair was not written together; the file is torn or edited)")
    return read_npz(data, npz_path), meta


def jsonable(x):
    """Numpy scalars/arrays to plain JSON types (and refuse NaN/inf via json's allow_nan)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def versions() -> dict:
    """Versions of the packages a result depends on (metadata; never compared on load)."""
    return {"jaxgrasp": jaxgrasp.__version__, "jax": jax.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "mujoco": mujoco.__version__}
