"""XLA settings read when JAX starts its CPU backend (no JAX import here: set them first)."""

import os

_COUNT = "xla_force_host_platform_device_count"


def device_count_flag(members: int) -> str:
    """The ``XLA_FLAGS`` entry giving a cohort of ``members`` runs its CPU devices (one per
    member plus device 0, see :class:`jaxgrasp.learn.Cohort`)."""
    return f"--{_COUNT}={int(members) + 1}"


def add_cpu_devices(members: int) -> None:
    """Ask for the CPU devices of a cohort of ``members`` runs; only effective before JAX's
    first computation, and a device count the user already set is kept."""
    flags = os.environ.get("XLA_FLAGS", "")
    if _COUNT not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {device_count_flag(members)}".strip()
