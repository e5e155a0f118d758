"""Scale-out drivers for the Rust binaries, on a Ray cluster (issue 26).

The work is done by the `xtask` binary built on every node; this package only schedules it:

- `python -m cluster render SCENE --out DIR --shards N`: one Ray task per shard runs
  `xtask render SCENE --out ... --shard K/N`, Ray retries failed tasks, and the driver runs
  `xtask merge` into DIR (byte-identical to an unsharded `xtask render`).
- `python -m cluster sweep DATASET --models auto,fast-small --seeds 0,1 --time 5m`: a Ray Tune
  trial per (model, seed) runs `xtask train` (each validation line of the run's
  `metrics.jsonl` is reported to Tune, so ASHA can stop hopeless trials) and `xtask eval`; the
  driver then runs `xtask compare` over the evaluated runs.

The Rust side knows nothing of Ray: the same `render --shard K/N` and `merge` run from a Slurm
array job (see `cluster/README.md`).
"""

__all__ = ["ClusterError"]


class ClusterError(Exception):
    """A failure the command line reports as one clear message and exit status 1."""
