"""A Dask scheduler and workers started as separate processes on this machine, for the tests
that run studies on a running cluster (``--scheduler``)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def running_cluster(log_dir: Path, workers: int = 2) -> Iterator[str]:
    """``dask scheduler`` and ``dask worker --nworkers WORKERS --nthreads 1`` bound to
    127.0.0.1 (logs in ``log_dir``); yields the scheduler's address once every worker joined,
    and stops them all (SIGINT, then kill) on exit."""
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    logs = [open(log_dir / name, "w") for name in ("scheduler.log", "worker.log")]
    procs = []
    try:
        scheduler = [*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port)]
        procs.append(
            subprocess.Popen(
                [*scheduler, "--no-dashboard"],
                cwd=ROOT,
                env=env,
                stdout=logs[0],
                stderr=subprocess.STDOUT,
            )
        )
        worker = [*dask, "worker", address, "--nworkers", str(workers), "--nthreads", "1"]
        worker += ["--no-dashboard", "--host", "127.0.0.1", "--death-timeout", "60"]
        procs.append(
            subprocess.Popen(worker, cwd=ROOT, env=env, stdout=logs[1], stderr=subprocess.STDOUT)
        )
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(workers, timeout=120)
        yield address
    finally:
        for proc in reversed(procs):
            proc.send_signal(signal.SIGINT)
        for proc in reversed(procs):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for log in logs:
            log.close()
