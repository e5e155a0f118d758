"""Command line: `python -m cluster render ...` and `python -m cluster sweep ...` (see README)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import ClusterError


def add_ray_options(p: argparse.ArgumentParser, per: str) -> None:
    p.add_argument("--address", help="Ray cluster to use (HOST:PORT of the head, ray://HOST:PORT, or auto); default: start a local Ray")
    p.add_argument("--local-cpus", type=int, help="CPUs of the local Ray started without --address (default: all cores)")
    p.add_argument("--num-cpus", type=float, default=1, help=f"CPUs Ray reserves for each {per}, also its xtask's threads (default 1)")
    p.add_argument(
        "--xtask",
        help="path of the xtask binary on the nodes (default: target/release/xtask under this checkout if it exists, else target/debug/xtask)",
    )


def check_numbers(args: argparse.Namespace) -> None:
    """Refuses counts Ray would reject with a traceback, or read as "unlimited"."""
    if not args.num_cpus > 0:
        raise ClusterError(f"--num-cpus {args.num_cpus:g}: give a positive number of CPUs")
    if args.local_cpus is not None and args.local_cpus < 1:
        raise ClusterError(f"--local-cpus {args.local_cpus}: give at least 1")
    for name in ("max_retries", "max_failures", "eval_max_views"):
        v = getattr(args, name, None)
        least = 1 if name == "eval_max_views" else 0
        if v is not None and v < least:
            raise ClusterError(f"--{name.replace('_', '-')} {v}: give at least {least}")


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="python -m cluster", description=__doc__)
    sub = top.add_subparsers(dest="command", required=True)

    r = sub.add_parser(
        "render",
        help="render a dataset as N shards on Ray, then merge",
        description="Render SCENE as N shards, one Ray task each (`xtask render --shard K/N`), then `xtask merge` into --out. "
        "Options not listed here (--preset, --res, --spp, --train, ...) go to `xtask render` unchanged.",
    )
    r.add_argument("scene", help="a .gltf/.glb file or the name of a scene in scenes/ (as for `xtask render`)")
    r.add_argument("--out", required=True, type=Path, help="dataset folder to write (must not exist or be empty)")
    r.add_argument("--shards", required=True, type=int, help="number of shards (Ray tasks)")
    r.add_argument("--shared-storage", action="store_true", help="--out is on storage every node sees: tasks write their shards there (DIR.shards/K)")
    r.add_argument("--max-retries", type=int, default=3, help="retries of a failed shard task (default 3)")
    r.add_argument("--keep-shards", action="store_true", help="keep DIR.shards/ after the merge")
    add_ray_options(r, "shard task")

    s = sub.add_parser(
        "sweep",
        help="train and evaluate every (model, seed) as Ray Tune trials, then compare",
        description="One Ray Tune trial per (model, seed): `xtask train` (each validation reported to Tune), `xtask eval`; then `xtask compare` of the evaluated runs into --out.",
    )
    s.add_argument("dataset", type=Path, help="dataset folder (on a path every node sees)")
    s.add_argument("--models", default="auto,fast-small,fast,paper", help="comma-separated: auto, fast, paper (train --model) or fast-small, fast-medium, fast-large (bench auto's fixed sizes)")
    s.add_argument("--seeds", default="0", help="comma-separated seeds (default 0)")
    s.add_argument("--time", help="training time budget per trial: 90s, 5m, 1h (default 5m unless --steps)")
    s.add_argument("--steps", type=int, help="training steps per trial")
    s.add_argument("--out", type=Path, help="sweep folder: runs/, tune/, compare.md, compare.png (default runs/sweep-<dataset name>)")
    s.add_argument("--asha", action="store_true", help="stop hopeless trials early (ASHA on val_psnr over the trainer's wall_s)")
    s.add_argument("--grace", help="ASHA: training time every trial gets before it can be stopped (default a fifth of --time)")
    s.add_argument("--eval-max-views", type=int, help="evaluate only the first N test views")
    s.add_argument("--max-failures", type=int, default=1, help="times Ray Tune retries a failed trial (default 1)")
    s.add_argument(
        "--force",
        action="store_true",
        help="replace the runs in OUT/runs that this sweep cannot continue (trained with other settings, not written by it, or refused on --resume) instead of refusing",
    )
    add_ray_options(s, "trial")
    return top


#: Options of `xtask render` that take no value (every other one takes one).
RENDER_SWITCHES = ("--force",)


def split_render_args(top: argparse.ArgumentParser, argv: list[str]) -> tuple[list[str], list[str]]:
    """Splits `render ...` into the driver's arguments and the options passed to `xtask render`
    (any option the driver does not know, with its value unless it is a switch or `--opt=v`),
    so that `--preset quick SCENE` never reads `quick` as the scene."""
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction)).choices["render"]
    known = sub._option_string_actions
    ours, theirs, i = [], [], 0
    while i < len(argv):
        tok = argv[i]
        name = tok.split("=", 1)[0]
        if tok.startswith("--") and name not in known:
            theirs.append(tok)
            if "=" not in tok and name not in RENDER_SWITCHES and i + 1 < len(argv):
                theirs.append(argv[i + 1])
                i += 1
        else:
            ours.append(tok)
            action = known.get(name)
            if action is not None and action.nargs != 0 and "=" not in tok and i + 1 < len(argv):
                ours.append(argv[i + 1])
                i += 1
        i += 1
    return ours, theirs


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = parser()
    extra: list[str] = []
    if argv[:1] == ["render"] and not {"-h", "--help"} & set(argv):
        ours, extra = split_render_args(top, argv[1:])
        argv = ["render", *ours]
    args = top.parse_args(argv)
    try:
        check_numbers(args)
        if args.command == "render":
            from . import render
            from .xtask import find_xtask

            binary, how = find_xtask(args.xtask)
            render.log(f"xtask: {binary} ({how})")
            job = render.RenderJob(
                scene=args.scene,
                out=args.out.resolve(),
                shards=args.shards,
                xtask=binary,
                num_cpus=args.num_cpus,
                shared_storage=args.shared_storage,
                max_retries=args.max_retries,
                keep_shards=args.keep_shards,
                render_args=extra,
            )
            render.run(job, address=args.address, local_cpus=args.local_cpus)
        else:
            from . import sweep

            sweep.run(sweep.spec_from_args(args))
        return 0
    except ClusterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
