"""`python -m cluster render`: one Ray task per shard runs `xtask render --shard K/N`, then
`xtask merge` writes the dataset.

Where the shards go:
- `--shared-storage` (DIR on a path every node sees): each task renders into
  `DIR.shards/K` itself; a re-run resumes the views already finished there.
- otherwise each task renders into a temporary folder on its node and returns the shard's files
  (relative path -> bytes) through Ray's object store; the driver writes them to
  `DIR.shards/K` (through a `.part` folder renamed when complete).
`xtask merge DIR.shards/0 ... --out DIR` then checks the shards and writes DIR, itself through a
temporary sibling renamed at the end, so DIR appears only complete. `DIR.shards` is removed
after a successful merge (kept with `--keep-shards`, and after a failure).
"""

from __future__ import annotations

import os
import shutil
import socket
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from . import ClusterError
from . import xtask as xt
from .raysession import ray_session

#: Options of `xtask render` that the driver sets itself.
OWN_FLAGS = ("--out", "--shard")

#: A task's temporary shard folder is `<tmp>/nerf-gt-shard-<worker pid>-<k>-<random>`.
TMP_PREFIX = "nerf-gt-shard-"


@dataclass
class RenderJob:
    """Everything a shard task needs, sent to it once."""

    scene: str
    out: Path
    shards: int
    xtask: str
    num_cpus: float = 1
    shared_storage: bool = False
    max_retries: int = 3
    keep_shards: bool = False
    render_args: list[str] = field(default_factory=list)
    #: The driver's working directory: the tasks run there when it exists on their node, so a
    #: relative scene path means the same file (and is recorded the same) as on the driver.
    workdir: str = field(default_factory=os.getcwd)

    def shards_root(self) -> Path:
        return self.out.with_name(self.out.name + ".shards")

    def shard_dir(self, k: int) -> Path:
        return self.shards_root() / str(k)

    def threads(self) -> int:
        return max(1, int(self.num_cpus))


def log(msg: str) -> None:
    print(f"[cluster] {msg}", file=sys.stderr, flush=True)


def render_shard(job: RenderJob, k: int) -> dict:
    """A Ray task: renders shard `k` with the node's xtask. Returns the node's name, seconds,
    and (without shared storage) the shard's files as {relative path: bytes}."""
    t0 = time.monotonic()
    node = node_name()
    tmp = None
    if job.shared_storage:
        out = job.shard_dir(k)
        out.parent.mkdir(parents=True, exist_ok=True)
    else:
        remove_dead_tmp(Path(tempfile.gettempdir()))
        tmp = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{os.getpid()}-{k}-"))
        out = tmp / "shard"
    cmd = [job.xtask, "render", job.scene, "--out", str(out), "--shard", f"{k}/{job.shards}", *job.render_args]
    if not xt.has_flag(job.render_args, "--threads"):
        cmd += ["--threads", str(job.threads())]
    prefix = f"[shard {k}/{job.shards} on {node}]"
    print(f"{prefix} {' '.join(cmd)}", flush=True)
    try:
        xt.run(
            cmd,
            f"shard {k}/{job.shards} (`xtask render` on {node})",
            cwd=job.workdir if os.path.isdir(job.workdir) else None,
            env=xt.with_threads(None, job.threads()),
            on_line=lambda line: print(f"{prefix} {line}", flush=True),
        )
        files = None
        if tmp is not None:
            files = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
        return {"shard": k, "node": node, "seconds": time.monotonic() - t0, "files": files}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def remove_dead_tmp(tmp: Path) -> None:
    """Removes the temporary shard folders whose worker is gone: a worker killed with its node
    (the retry runs elsewhere) cannot clean up after itself."""
    for d in tmp.glob(f"{TMP_PREFIX}*"):
        pid = d.name[len(TMP_PREFIX) :].split("-", 1)[0]
        if d.is_dir() and pid.isdigit() and not xt.pid_alive(int(pid)):
            shutil.rmtree(d, ignore_errors=True)


def node_name() -> str:
    """This host's name and, inside Ray, the start of its node id (two nodes may share a host)."""
    try:
        import ray

        return f"{socket.gethostname()}/{ray.get_runtime_context().get_node_id()[:8]}"
    except Exception:  # outside a Ray worker
        return socket.gethostname()


def write_shard(folder: Path, files: dict) -> None:
    """Writes a shard's files under `folder`, through `folder.part` renamed when complete."""
    part = folder.with_name(folder.name + ".part")
    for d in (part, folder):
        if d.exists():
            shutil.rmtree(d)
    for rel, data in files.items():
        p = part / rel
        if p.resolve().parent != part.resolve() and part.resolve() not in p.resolve().parents:
            raise ClusterError(f"shard file {rel!r} points outside its folder")
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    part.rename(folder)


def check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ClusterError(f"--out {out}: exists and is not an empty folder; the render writes a new dataset folder")


def submit(ray, job: RenderJob):
    # Retried: a dead worker or node, and xtask's `XtaskFailed` (an I/O error on its node, 74; a
    # stop by a signal, 130; a crash). Never its refusals (`XtaskRefused`, 1): they would repeat.
    task = ray.remote(render_shard).options(
        num_cpus=job.num_cpus,
        max_retries=job.max_retries,
        retry_exceptions=[xt.XtaskFailed],
        name="render_shard",
    )
    return {task.remote(job, k): k for k in range(job.shards)}


def run(job: RenderJob, address: Optional[str] = None, local_cpus: Optional[int] = None) -> Path:
    """Renders every shard on the cluster and merges them into `job.out`; returns it."""
    if job.shards < 1:
        raise ClusterError(f"--shards {job.shards}: give at least 1 shard")
    for flag in OWN_FLAGS:
        if xt.has_flag(job.render_args, flag):
            raise ClusterError(f"{flag} is set by the driver; leave it out of the render options")
    check_out(job.out)
    t0 = time.monotonic()
    wrote_root = not job.shared_storage and not job.shards_root().exists()
    try:
        render_all(job, t0, address, local_cpus)
    except BaseException:
        # Shards that came through the object store cannot be resumed: leave nothing behind.
        # (Shards on shared storage stay, so a re-run resumes their finished views.)
        if wrote_root:
            shutil.rmtree(job.shards_root(), ignore_errors=True)
        raise
    merge(job)
    if not job.keep_shards:
        shutil.rmtree(job.shards_root(), ignore_errors=True)
    log(f"dataset {job.out} from {job.shards} shards in {time.monotonic() - t0:.1f} s")
    return job.out


def render_all(job: RenderJob, t0: float, address: Optional[str], local_cpus: Optional[int]) -> None:
    """Runs every shard task, writing the shards that come through the object store."""
    mode = "shared storage" if job.shared_storage else "Ray's object store"
    with ray_session(address, local_cpus) as ray:
        log(f"{job.shards} shard tasks ({job.num_cpus:g} CPU each, up to {job.max_retries} retries), shards through {mode} into {job.shards_root()}")
        pending = submit(ray, job)
        done_count, last_note = 0, time.monotonic()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=5.0)
            if not ready:
                if time.monotonic() - last_note > 30:
                    waiting = ", ".join(str(k) for k in sorted(pending.values()))
                    log(f"{done_count}/{job.shards} shards done, {time.monotonic() - t0:.0f} s; waiting for shard(s) {waiting}")
                    last_note = time.monotonic()
                continue
            for ref in ready:
                k = pending.pop(ref)
                try:
                    res = ray.get(ref)
                except Exception as e:  # xtask's refusal, or the last retry's error
                    for other in pending:
                        ray.cancel(other, force=True)
                    raise ClusterError(shard_failure(job, k, e)) from e
                if res["files"] is not None:
                    write_shard(job.shard_dir(k), res.pop("files"))
                done_count += 1
                last_note = time.monotonic()
                log(f"shard {k}/{job.shards} done on {res['node']} in {res['seconds']:.1f} s ({done_count}/{job.shards} done, {last_note - t0:.1f} s)")
                del res


def merge(job: RenderJob) -> None:
    cmd = [job.xtask, "merge", *(str(job.shard_dir(k)) for k in range(job.shards)), "--out", str(job.out)]
    if Path(job.scene).is_file():
        cmd += ["--scene", job.scene]
    log(" ".join(cmd))
    try:
        xt.run(cmd, "`xtask merge`", on_line=lambda line: print(line, flush=True))
    except (xt.XtaskFailed, xt.XtaskRefused) as e:
        raise ClusterError(f"{e}\n(the shards are kept in {job.shards_root()})") from e


def shard_failure(job: RenderJob, k: int, e: BaseException) -> str:
    """What went wrong with shard `k`: xtask's own message when it refused the shard (not
    retried), else the last attempt's error, without Ray's wrapping traceback."""
    cause = getattr(e, "cause", None)
    if isinstance(cause, xt.XtaskRefused):
        return str(cause)
    what = str(cause) if isinstance(cause, BaseException) else f"{type(e).__name__}: {e}"
    return f"shard {k}/{job.shards} failed after up to {job.max_retries} retries: {what}"
