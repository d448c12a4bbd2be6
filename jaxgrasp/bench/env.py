"""What a results file records about where it was produced: versions, device, git revision."""

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

import jax

_PACKAGES = ("jaxgrasp", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "scipy", "trimesh",
             "optax", "matplotlib")


def versions() -> dict:
    out = {"python": platform.python_version()}
    for p in _PACKAGES:
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = None
    return out


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def device() -> dict:
    devs = jax.devices()
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    return {
        "platform": jax.default_backend(),
        "devices": [str(getattr(d, "device_kind", d)) for d in devs],
        "device_count": len(devs),
        "cpu": _cpu_model(),
        "cpu_cores": cores,
        "machine": platform.machine(),
        "system": platform.system(),
        "hostname": platform.node(),
    }


def git_revision(root: str | os.PathLike | None = None) -> dict:
    root = Path(root) if root else Path(__file__).resolve().parents[2]

    def git(*args):
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                              timeout=10)

    try:
        rev = git("rev-parse", "HEAD")
        if rev.returncode != 0:
            return {"revision": None, "dirty": None}
        dirty = git("status", "--porcelain", "--untracked-files=no")
        return {"revision": rev.stdout.strip(), "dirty": bool(dirty.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"revision": None, "dirty": None}
