"""Finding the prebuilt `xtask` binary and running it as a child process that dies with its
parent (a Ray worker that is killed or cancelled takes its render or training with it)."""

from __future__ import annotations

import collections
import ctypes
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

from . import ClusterError

#: The repository root (the parent of this package).
REPO_ROOT = Path(__file__).resolve().parent.parent

#: Where the workspace builds put the binary, in order of preference.
DEFAULT_BINARIES = ("target/release/xtask", "target/debug/xtask")

#: `xtask`'s exit statuses (docs/design.md, "Exit codes"): 1, it refused its input (a missing
#: scene, a bad option value, a dataset folder of other settings) with its own message;
#: 74, an I/O error of this node's storage (disk full, a quota, an unwritable or read-only
#: output folder, a disk error); 130, stopped by a signal with its work saved (a re-run resumes).
EXIT_REFUSED, EXIT_NODE_IO, EXIT_STOPPED = 1, 74, 130

#: Exit statuses that come out the same on every node, so they are not retried: xtask's refusal,
#: and 2, a usage error as clap reports it. Anything else is worth a retry, on another node:
#: 74 and 130 (a resumed run continues), a kill by a signal, a panic's 101, a missing binary.
REFUSED_EXITS = (EXIT_REFUSED, 2)

#: What the statuses that are no crash mean, for messages.
EXIT_MEANINGS = {
    EXIT_NODE_IO: "an I/O error on this node: disk full, quota, permission or a disk error",
    EXIT_STOPPED: "stopped by a signal; its work is saved",
}


class XtaskFailed(Exception):
    """`xtask` failed in a way another attempt may not: an I/O error on the node (74), stopped
    by a signal (130), crashed or killed (a node's memory, a killed process, a node without the
    binary). Worth a retry on a cluster, which resumes what was saved."""

    def __init__(self, what: str, returncode: int, tail: Sequence[str]):
        self.what, self.returncode, self.tail = what, returncode, list(tail)
        super().__init__(describe_exit(what, returncode, tail))

    def __reduce__(self):
        return (type(self), (self.what, self.returncode, self.tail))


class XtaskRefused(Exception):
    """`xtask` refused its input with an error message (exit status 1, or 2 for a usage error):
    the same on every node, never retried."""

    def __init__(self, what: str, returncode: int, tail: Sequence[str]):
        self.what, self.returncode, self.tail = what, returncode, list(tail)
        super().__init__(describe_exit(what, returncode, tail))

    def __reduce__(self):
        return (type(self), (self.what, self.returncode, self.tail))


def failure(what: str, returncode: int, tail: Sequence[str]) -> Exception:
    """The exception for `xtask` ending with `returncode` (non-zero)."""
    cls = XtaskRefused if returncode in REFUSED_EXITS else XtaskFailed
    return cls(what, returncode, tail)


def describe_exit(what: str, returncode: int, tail: Sequence[str]) -> str:
    how = f"was killed by signal {-returncode}" if returncode < 0 else f"exited with status {returncode}"
    if returncode in (EXIT_NODE_IO, EXIT_STOPPED):
        how += f" ({EXIT_MEANINGS[returncode]})"
    lines = "".join(f"\n    {line}" for line in tail)
    return f"{what} {how}" + (f"; its last output:{lines}" if lines else "")


def find_xtask(path: Optional[str]) -> tuple[str, str]:
    """The binary to run and how it was chosen: `path` as given (it must exist here only when it
    is meant for this machine too, so a missing one is not an error), else
    `target/release/xtask` if it exists, else `target/debug/xtask`, under the repository root."""
    if path:
        p = Path(path).expanduser()
        return (str(p.resolve()) if p.exists() else str(p)), "--xtask"
    for rel in DEFAULT_BINARIES:
        p = REPO_ROOT / rel
        if p.is_file():
            return str(p), f"the {rel.split('/')[1]} build"
    raise ClusterError(
        f"no xtask binary in {REPO_ROOT / 'target'}: build it with `cargo build --release -p xtask` "
        "(or the workspace build), or give --xtask PATH"
    )


def _die_with_parent() -> None:
    """In the child before exec: SIGKILL when the parent thread that started it goes (Linux),
    and the default Ctrl-C and SIGTERM dispositions (a Ray worker ignores SIGINT, which an exec
    would pass on, and xtask could not install its Ctrl-C handler)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def child_preexec() -> Optional[Callable[[], None]]:
    return _die_with_parent if sys.platform.startswith("linux") else None


def pid_alive(pid: int) -> bool:
    """Whether a process `pid` exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def run(
    cmd: Sequence[str],
    what: str,
    *,
    cwd: Optional[str] = None,
    env: Optional[dict] = None,
    on_line: Optional[Callable[[str], None]] = None,
    tail_lines: int = 20,
) -> list[str]:
    """Runs `cmd`, handing each line of its merged stdout/stderr to `on_line`; returns the lines.
    Raises `XtaskRefused` on exit status 1 or 2, `XtaskFailed` on any other failure (74, 130,
    a signal, a crash). The child
    is killed if this process dies or this call is interrupted."""
    if not Path(cmd[0]).is_file():
        raise XtaskFailed(what, 127, [f"no such binary on {os.uname().nodename}: {cmd[0]}"])
    proc = subprocess.Popen(
        list(cmd),
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        errors="replace",
        bufsize=1,
        preexec_fn=child_preexec(),
    )
    lines: list[str] = []
    tail: collections.deque[str] = collections.deque(maxlen=tail_lines)
    try:
        assert proc.stdout is not None
        for raw in proc.stdout:
            line = raw.rstrip("\n")
            lines.append(line)
            tail.append(line)
            if on_line:
                on_line(line)
        rc = proc.wait()
    finally:
        stop(proc)
        if proc.stdout is not None:
            proc.stdout.close()
    if rc != 0:
        raise failure(what, rc, tail)
    return lines


def stop(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    """Ends `proc` if it still runs: SIGTERM, then SIGKILL after `grace_s`."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def with_threads(env: Optional[dict], threads: Optional[int]) -> dict:
    """The environment for a child that should use `threads` cores (rayon's global pool)."""
    out = dict(os.environ if env is None else env)
    if threads:
        out["RAYON_NUM_THREADS"] = str(threads)
    return out


def has_flag(args: Iterable[str], flag: str) -> bool:
    return any(a == flag or a.startswith(flag + "=") for a in args)
