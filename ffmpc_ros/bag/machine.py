"""Which machine and numerical stack recorded a bag (ROS-free).

Lockstep runs are deterministic on one machine, but the last bits of a result depend on the CPU,
the BLAS kernels OpenBLAS picks (``OPENBLAS_CORETYPE`` changes them) and the versions of the
numerical libraries. The recorder stores :func:`machine_fingerprint` in the bag's
``ffmpc_machine`` metadata record; a re-run demands bit-identical outputs only when the
fingerprint of the machine re-running equals the recorded one, and outputs equal within a stated
tolerance everywhere (:mod:`ffmpc_ros.bag.rerun`).
"""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping
from importlib import metadata

#: Metadata record holding the fingerprint.
MACHINE_RECORD = "ffmpc_machine"
#: Distributions whose version changes the numbers a controller computes.
NUMERICAL_PACKAGES = ("numpy", "scipy", "pin", "crocoddyl", "mim-solvers", "ffmpc")
#: Environment variables that change the BLAS kernels (and so the last bits).
NUMERICAL_ENVIRONMENT = ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OPENBLAS_NUM_THREADS")


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def machine_fingerprint() -> dict[str, str]:
    """{key: value} describing this machine's CPU, BLAS settings and numerical package versions."""
    fingerprint = {
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "python": platform.python_version(),
    }
    fingerprint.update({f"version.{p}": _version(p) for p in NUMERICAL_PACKAGES})
    fingerprint.update({f"env.{k}": os.environ.get(k, "") for k in NUMERICAL_ENVIRONMENT})
    return fingerprint


def same_machine(recorded: Mapping[str, str] | None) -> bool:
    """Whether a recorded fingerprint equals this machine's (False when none was recorded)."""
    return recorded is not None and dict(recorded) == machine_fingerprint()
