"""Connecting to a Ray cluster, or starting a small local one, for the length of a command."""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import threading
from pathlib import Path
from typing import Iterator, Optional

from . import ClusterError

#: Seconds to wait for a TCP connection to `--address` before calling it unreachable.
CONNECT_TIMEOUT_S = 5.0

#: Seconds `ray.init(address=...)` may take in all. Something that accepts connections but
#: does not answer as a Ray head (a wrong port, a firewall, a head still starting) makes Ray
#: retry for minutes; past this the command ends with exit status 1 instead.
INIT_DEADLINE_S = 20.0


def import_ray():
    try:
        import ray  # noqa: F401
    except ImportError as e:
        raise ClusterError(
            f"Ray is not installed here ({e}): python3 -m venv .venv-cluster && "
            ".venv-cluster/bin/pip install -r cluster/requirements.txt"
        ) from e
    return ray


def host_port(address: str) -> Optional[tuple[str, int]]:
    """`(host, port)` of a `HOST:PORT` or `ray://HOST:PORT` address; None for `auto` and the like."""
    rest = address.split("://", 1)[1] if "://" in address else address
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return host.strip("[]") or "127.0.0.1", int(port)


def check_reachable(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Fails fast with a clear message when nothing listens at `address` (Ray itself may keep
    retrying for minutes)."""
    hp = host_port(address)
    if hp is None:
        return
    try:
        with socket.create_connection(hp, timeout=timeout_s):
            pass
    except OSError as e:
        if address.startswith("ray://"):
            how = f"its head must run the Ray Client server (`ray start --head --ray-client-server-port={hp[1]}`)"
        else:
            how = f"start its head with `ray start --head --port={hp[1]}`"
        raise ClusterError(f"cannot reach the Ray cluster at {address} ({e}); {how}, or leave out --address to start a local Ray") from e


@contextlib.contextmanager
def deadline(seconds: float, message: str) -> Iterator[None]:
    """Ends the process with `error: message` and exit status 1 if the body takes longer than
    `seconds`. For a blocking call that cannot be interrupted (`ray.init` retrying a silent
    address); the command has written nothing yet, so there is nothing to clean up."""

    def expire() -> None:
        print(f"error: {message}", file=sys.stderr, flush=True)
        os._exit(1)

    timer = threading.Timer(seconds, expire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


@contextlib.contextmanager
def ray_session(address: Optional[str], local_cpus: Optional[int]) -> Iterator[object]:
    """Ray connected for the body: to `address` (shipping this package to the workers), or a
    new local instance with `local_cpus` CPUs (default: all cores) and no dashboard, shut down
    at the end. A session the caller already opened (`ray.is_initialized()`) is used as is."""
    # Each shard's or trial's lines carry its own prefix: show them all, not "[repeated 2x]".
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    common = dict(logging_level=logging.WARNING, log_to_driver=True)
    if address:
        check_reachable(address)
        package = str(Path(__file__).resolve().parent)
        silent = (
            f"the Ray cluster at {address} did not answer within {INIT_DEADLINE_S:.0f} s "
            "(something listens there, but not a Ray head, or the head is not up yet)"
        )
        try:
            with deadline(INIT_DEADLINE_S, silent):
                ray.init(address=address, runtime_env={"py_modules": [package], "excludes": ["tests", "__pycache__"]}, **common)
        except Exception as e:  # Ray raises ConnectionError, RuntimeError, ValueError ...
            raise ClusterError(f"cannot connect to the Ray cluster at {address}: {e}") from e
    else:
        # Workers of a local instance see the driver's sys.path, so `cluster` imports there.
        ray.init(num_cpus=local_cpus or os.cpu_count() or 1, include_dashboard=False, **common)
    try:
        yield ray
    finally:
        ray.shutdown()
