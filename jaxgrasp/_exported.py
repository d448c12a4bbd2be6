"""Traced programs kept on disk beside the persistent compilation cache (``jax.export``).

JAX's cache keeps compiled code, but a fresh process still traces and lowers a function
before it can look the code up: ~2 s for each of the C trial's contact stage and epsilon per
batch shape. :func:`stored_jit` keeps the lowered program of each input signature in
``<compilation cache>/exported``, keyed by the function's name and static arguments, the
signature, the platform, the JAX and jaxlib versions and the source of this package; a later
process deserializes it instead of tracing (the same program: the same values, bit for bit).
With no compilation cache enabled it is plain ``jax.jit``.
"""

import functools
import hashlib
import os
import threading
import warnings
from functools import cache
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np

#: Where under the compilation cache (JAX's own entries are files ending in "-cache").
SUBDIR = "exported"


@cache
def source_digest() -> str:
    """sha256 of this package's Python sources: any code change is a new program."""
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def array_digest(tree) -> str:
    """sha256 of a pytree's array leaves (shapes, dtypes, bytes): constants a stored program
    closes over, for its ``static`` key."""
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        a = np.asarray(leaf)
        digest.update(repr((a.shape, str(a.dtype))).encode())
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()


def locked_cache(factory):
    """``functools.cache`` of a factory of stored functions, made once when several threads
    ask at once (the tail's and the demo optimizer's threads): two would each trace, export
    and compile the same program."""
    cached = cache(factory)
    lock = threading.Lock()

    @functools.wraps(factory)
    def get(*args):
        with lock:
            return cached(*args)

    return get


def _directory() -> Path | None:
    cache_dir = jax.config.jax_compilation_cache_dir
    return None if not cache_dir else Path(cache_dir) / SUBDIR


def _aval(x):
    """(shape, dtype, weak type) of an argument; from its attributes (np.shape and str of a
    dtype cost ~10 us each, on every trial call)."""
    try:
        return x.shape, x.dtype, bool(getattr(x, "weak_type", False))
    except AttributeError:  # a Python scalar
        return np.shape(x), jnp.result_type(x), False


def _spec(x):
    return jax.ShapeDtypeStruct(np.shape(x), jnp.result_type(x),
                                weak_type=bool(getattr(x, "weak_type", False)))


def stored_jit(fun, *, name: str, static: str = "", compiler_options=None):
    """``jax.jit(fun, compiler_options=...)`` whose traced program, per input signature, is
    stored on disk and read back by later processes (see the module docstring).

    ``name`` and ``static`` (a string of every value ``fun`` closes over that changes its
    program: static arguments, parameters) are part of the key. Arguments must be arrays or
    pytrees of arrays; under a trace (an outer ``jit``/``vmap``) it is plain ``jax.jit``. A
    file that cannot be read is traced and written again."""
    jitted = jax.jit(fun, compiler_options=compiler_options)
    programs: dict = {}
    lock = threading.Lock()

    def call(*args):
        # Every trial call passes here: the signature from the leaves' own attributes.
        leaves, tree = jax.tree.flatten(args)
        if not jax.config.jax_compilation_cache_dir or any(
                isinstance(x, jax.core.Tracer) for x in leaves):
            return jitted(*args)
        signature = (tree, tuple(map(_aval, leaves)))
        program = programs.get(signature)
        if program is None:
            with lock:  # two tail threads meeting a new shape: one traces it
                program = programs.get(signature)
                if program is None:
                    program = _load_or_export(jitted, tree, leaves, _directory(), name,
                                              static, signature, compiler_options)
                    programs[signature] = program
        return program(*args)

    call.jitted = jitted
    # the programs it holds, stored or jitted (as ``jax.jit``'s own count)
    call._cache_size = lambda: len(programs) + jitted._cache_size()
    return call


def _load_or_export(jitted, tree, leaves, directory, name, static, signature, options):
    key = hashlib.sha256(repr((name, static, signature, jax.default_backend(), jax.__version__,
                               jaxlib.__version__, bool(jax.config.jax_enable_x64),
                               source_digest())).encode())
    path = directory / f"{name}-{key.hexdigest()[:32]}.bin"
    exported = None
    if path.exists():
        try:
            exported = jax.export.deserialize(bytearray(path.read_bytes()))
        except Exception as err:  # noqa: BLE001 - a damaged file: trace again
            warnings.warn(f"could not read the stored program {path} ({err}); tracing it",
                          stacklevel=3)
    if exported is None:
        try:
            specs = [_spec(x) for x in leaves]
            exported = jax.export.export(jitted)(*jax.tree.unflatten(tree, specs))
            directory.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
            tmp.write_bytes(exported.serialize())
            tmp.replace(path)  # whole or absent: another process may be reading
        except Exception as err:  # noqa: BLE001 - no serialization here: jit as usual
            warnings.warn(f"could not store the program {name} ({err}); it is traced in "
                          "each process", stacklevel=3)
            return jitted
    return jax.jit(exported.call, compiler_options=options)
