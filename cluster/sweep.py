"""`python -m cluster sweep`: one Ray Tune trial per (model, seed).

A trial runs `xtask train DATASET --out OUT/runs/NAME --seed S ...` as a child process, tails the
run's `metrics.jsonl` and reports every validation line (`val_psnr`, `wall_s`, `step`,
`val_depth_mae`) to Tune, then runs `xtask eval` and reports the test figures. With `--asha`
an ASHA scheduler (metric `val_psnr`, mode max, time attribute the trainer's `wall_s`) stops
trials that fall behind at its rungs; a stopped trial's worker goes away and its `xtask train`
with it (the child is killed when its parent dies). At the end the driver runs
`xtask compare` over the evaluated runs into OUT (`compare.md`, `compare.png`).

Model names: `auto`, `fast`, `paper` are `xtask train --model`; `fast-small`, `fast-medium`,
`fast-large` are the fixed sizes of `cargo xtask bench auto` (xtask/src/bench/auto.rs):
the `fast` preset's config (read from a one-step probe run, so every other setting is the
trainer's own) with the same model fields changed, passed with `--config`. Run folders are
named as `bench auto` names them: `MODEL` for the first seed, `MODEL-seedS` for the others.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from . import ClusterError
from . import xtask as xt
from .raysession import ray_session

#: `xtask train --model` names.
TRAIN_MODELS = ("auto", "fast", "paper")

#: bench auto's fixed sizes: the fields of the `fast` preset's model config they change
#: (xtask/src/bench/auto.rs `config_of`; fast-medium is the preset itself).
FIXED_SIZES: dict[str, dict] = {
    "fast-small": {"levels": 8, "log2_table_size": 15, "finest_resolution": 256, "grid_resolution": 32, "steps_per_diagonal": 256},
    "fast-medium": {},
    "fast-large": {"log2_table_size": 19, "finest_resolution": 2048, "grid_resolution": 128, "steps_per_diagonal": 1024},
}

#: Seconds between looks at a training run's metrics.jsonl.
POLL_S = 0.5


@dataclass
class SweepSpec:
    """Everything a trial needs, sent to it once."""

    dataset: Path
    models: list[str]
    seeds: list[int]
    out: Path
    xtask: str
    time: Optional[str] = None
    steps: Optional[int] = None
    asha: bool = False
    grace_s: Optional[float] = None
    eval_max_views: Optional[int] = None
    max_failures: int = 1
    num_cpus: float = 1
    address: Optional[str] = None
    local_cpus: Optional[int] = None
    workdir: str = field(default_factory=os.getcwd)

    def run_dir(self, model: str, seed: int) -> Path:
        return self.out / "runs" / run_name(model, seed, seed == self.seeds[0])

    def threads(self) -> int:
        return max(1, int(self.num_cpus))


def run_name(model: str, seed: int, first: bool) -> str:
    """bench auto's run folder name: the model for the first seed, `MODEL-seedS` after."""
    return model if first else f"{model}-seed{seed}"


def parse_duration(s: str) -> float:
    """Seconds of `90s`, `5m`, `1h` (the forms `xtask train --time` takes)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(s|m|min|h)?\s*", s)
    if not m or float(m.group(1)) <= 0:
        raise ClusterError(f"bad duration '{s}' (e.g. 90s, 5m, 1h)")
    return float(m.group(1)) * {"s": 1, None: 1, "m": 60, "min": 60, "h": 3600}[m.group(2)]


def comma_list(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def spec_from_args(args) -> SweepSpec:
    from .xtask import find_xtask

    models = comma_list(args.models)
    known = (*TRAIN_MODELS, *FIXED_SIZES)
    for m in models:
        if m not in known:
            raise ClusterError(f"--models: unknown model '{m}' (of {', '.join(known)})")
    if not models or len(set(models)) != len(models):
        raise ClusterError(f"--models '{args.models}': give each model once")
    try:
        seeds = [int(s) for s in comma_list(args.seeds)]
    except ValueError as e:
        raise ClusterError(f"--seeds '{args.seeds}': comma-separated integers") from e
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ClusterError(f"--seeds '{args.seeds}': give each seed (>= 0) once")
    if args.steps is not None and args.steps < 1:
        raise ClusterError("--steps must be positive")
    time_ = args.time or (None if args.steps else "5m")
    if time_:
        # In the one form `xtask train --time` surely reads the same.
        time_ = f"{parse_duration(time_):g}s"
    grace = parse_duration(args.grace) if args.grace else None
    if args.asha and not time_:
        raise ClusterError("--asha needs --time: its rungs are points of training time")
    if not args.dataset.is_dir():
        raise ClusterError(f"{args.dataset}: no such dataset folder")
    if not (args.dataset / "transforms_train.json").is_file():
        raise ClusterError(f"{args.dataset}: not a dataset (no transforms_train.json); `xtask render` or `python -m cluster render` writes one")
    binary, how = find_xtask(args.xtask)
    print(f"[cluster] xtask: {binary} ({how})", file=sys.stderr, flush=True)
    dataset = args.dataset.resolve()
    out = (args.out or Path("runs") / f"sweep-{dataset.name}").resolve()
    return SweepSpec(
        dataset=dataset,
        models=models,
        seeds=seeds,
        out=out,
        xtask=binary,
        time=time_,
        steps=args.steps,
        asha=args.asha,
        grace_s=grace,
        eval_max_views=args.eval_max_views,
        max_failures=args.max_failures,
        num_cpus=args.num_cpus,
        address=args.address,
        local_cpus=args.local_cpus,
    )


class JsonlTail:
    """The complete lines added to a JSON-lines file since the last call (from the start again
    if the file was replaced by a shorter one)."""

    def __init__(self, path: Path):
        self.path, self.offset = path, 0

    def read(self) -> list[dict]:
        try:
            with open(self.path, "rb") as f:
                f.seek(0, os.SEEK_END)
                if f.tell() < self.offset:
                    self.offset = 0
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return []
        end = data.rfind(b"\n") + 1
        self.offset += end
        out = []
        for line in data[:end].splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
        return out


def val_metrics(rec: dict) -> dict:
    """The Tune result of one validation line of metrics.jsonl."""
    out = {"val_psnr": float(rec["val_psnr"]), "wall_s": float(rec.get("wall_s", 0.0)), "step": int(rec.get("step", 0))}
    if rec.get("val_depth_mae") is not None:
        out["val_depth_mae"] = float(rec["val_depth_mae"])
    return out


def fixed_size_config(spec: SweepSpec, model: str, probe: Path, log) -> dict:
    """The training config of a bench fixed size: the `fast` preset's, as a one-step probe run
    on this dataset writes it, with the size's model fields."""
    if probe.exists():
        shutil.rmtree(probe)
    cmd = [spec.xtask, "train", str(spec.dataset), "--out", str(probe), "--model", "fast", "--steps", "1"]
    try:
        xt.run(cmd, f"the probe run for {model}", cwd=cwd_of(spec), env=xt.with_threads(None, spec.threads()), on_line=log)
        cfg = json.loads((probe / "config.json").read_text())
    finally:
        shutil.rmtree(probe, ignore_errors=True)
    if cfg.get("model", {}).get("kind") != "fast":
        raise ClusterError(f"the probe run's config has no fast model: {cfg.get('model')}")
    for k in FIXED_SIZES[model]:
        if k not in cfg["model"]:
            raise ClusterError(f"the fast model config has no field '{k}' any more: update FIXED_SIZES in {__file__}")
    cfg["model"].update(FIXED_SIZES[model])
    # Resolved from the dataset again; budget and seed come from the command line.
    cfg.update(bounds=None, steps=None, time_budget_s=None)
    return cfg


def cwd_of(spec: SweepSpec) -> Optional[str]:
    return spec.workdir if os.path.isdir(spec.workdir) else None


def trial(config: dict, spec: SweepSpec) -> None:
    """A Ray Tune trial: train (validations reported as they appear), evaluate, report."""
    from ray import tune

    model, seed = config["model"], int(config["seed"])
    run = spec.run_dir(model, seed)
    runs = run.parent
    runs.mkdir(parents=True, exist_ok=True)
    for stale in (run, runs / f"{run.name}.config.json"):
        if stale.is_dir():
            shutil.rmtree(stale)
        elif stale.exists():
            stale.unlink()
    log_path = runs / f"{run.name}.log"
    with open(log_path, "w") as logf:

        def log(line: str) -> None:
            logf.write(line + "\n")
            logf.flush()

        cmd = [spec.xtask, "train", str(spec.dataset), "--out", str(run), "--seed", str(seed)]
        if model in FIXED_SIZES and FIXED_SIZES[model]:
            cfg_path = runs / f"{run.name}.config.json"
            cfg_path.write_text(json.dumps(fixed_size_config(spec, model, runs / f"{run.name}.probe", log), indent=2))
            cmd += ["--config", str(cfg_path)]
        else:
            cmd += ["--model", "fast" if model == "fast-medium" else model]
        if spec.time:
            cmd += ["--time", spec.time]
        if spec.steps:
            cmd += ["--steps", str(spec.steps)]
        log("$ " + " ".join(cmd))
        proc = subprocess.Popen(
            cmd,
            cwd=cwd_of(spec),
            env=xt.with_threads(None, spec.threads()),
            stdin=subprocess.DEVNULL,
            stdout=logf,
            stderr=subprocess.STDOUT,
            preexec_fn=xt.child_preexec(),
        )
        tail = JsonlTail(run / "metrics.jsonl")
        last = None
        try:
            while True:
                rc = proc.poll()
                for rec in tail.read():
                    if rec.get("val_psnr") is not None:
                        last = val_metrics(rec)
                        tune.report(last)
                if rc is not None:
                    break
                time.sleep(POLL_S)
        finally:
            xt.stop(proc)
        if rc != 0:
            raise xt.failure(f"training {run.name} (see {log_path})", rc, log_tail(log_path))
        cmd = [spec.xtask, "eval", str(run)]
        if spec.eval_max_views:
            cmd += ["--max-views", str(spec.eval_max_views)]
        log("$ " + " ".join(cmd))
        xt.run(cmd, f"evaluating {run.name} (see {log_path})", cwd=cwd_of(spec), env=xt.with_threads(None, spec.threads()), on_line=log)
    report = json.loads((run / "report.json").read_text())
    final = dict(last or {"wall_s": float(report.get("train_wall_s") or 0.0)})
    final.update(
        evaluated=True,
        test_psnr=report.get("final_psnr"),
        test_ssim=report.get("ssim"),
        test_depth_mae=report.get("depth_mae"),
        off_surface_mass=report.get("off_surface_mass"),
        steps=report.get("train_steps"),
    )
    tune.report({k: v for k, v in final.items() if v is not None})


def log_tail(path: Path, n: int = 15) -> list[str]:
    try:
        return path.read_text(errors="replace").splitlines()[-n:]
    except OSError:
        return []


def scheduler_of(spec: SweepSpec):
    if not spec.asha:
        return None
    from ray.tune.schedulers import ASHAScheduler

    budget = parse_duration(spec.time)
    grace = spec.grace_s or budget / 5
    # max_t beyond the budget: a result at max_t makes ASHA stop the trial, before its eval.
    return ASHAScheduler(time_attr="wall_s", max_t=2 * budget, grace_period=grace, reduction_factor=3)


def run(spec: SweepSpec) -> Path:
    """Runs the sweep and the comparison; returns the sweep folder."""
    t0 = time.monotonic()
    with ray_session(spec.address, spec.local_cpus):
        from ray import tune

        spec.out.mkdir(parents=True, exist_ok=True)

        trainable = tune.with_resources(tune.with_parameters(trial, spec=spec), {"cpu": spec.num_cpus})
        tuner = tune.Tuner(
            trainable,
            param_space={"model": tune.grid_search(spec.models), "seed": tune.grid_search(spec.seeds)},
            tune_config=tune.TuneConfig(metric="val_psnr", mode="max", scheduler=scheduler_of(spec)),
            run_config=tune.RunConfig(
                name="sweep",
                storage_path=str(spec.out / "tune"),
                failure_config=tune.FailureConfig(max_failures=spec.max_failures),
                verbose=1,
            ),
        )
        results = tuner.fit()
        rows = []
        for r in results:
            m = r.metrics or {}
            model, seed = r.config["model"], int(r.config["seed"])
            status = "evaluated" if m.get("evaluated") else ("failed" if r.error else "stopped early")
            rows.append((model, seed, status, m, r.error))
    rows.sort(key=lambda row: (spec.models.index(row[0]), spec.seeds.index(row[1])))
    print(trials_table(spec, rows), flush=True)
    evaluated = [spec.run_dir(model, seed) for model, seed, status, _, _ in rows if status == "evaluated"]
    if evaluated:
        cmd = [spec.xtask, "compare", *map(str, evaluated), "--out", str(spec.out)]
        print("[cluster] " + " ".join(cmd), file=sys.stderr, flush=True)
        try:
            xt.run(cmd, "`xtask compare`", on_line=lambda line: print(line, flush=True))
        except (xt.XtaskFailed, xt.XtaskRefused) as e:
            raise ClusterError(str(e)) from e
    print(f"[cluster] sweep of {len(rows)} trials in {time.monotonic() - t0:.0f} s: {spec.out}", file=sys.stderr, flush=True)
    failed = [(model, seed, err) for model, seed, status, _, err in rows if status == "failed"]
    if failed:
        lines = "".join(f"\n  {run_name(m, s, s == spec.seeds[0])}: {first_line(err)}" for m, s, err in failed)
        raise ClusterError(f"{len(failed)} of {len(rows)} trials failed (logs in {spec.out / 'runs'}):{lines}")
    if not evaluated:
        raise ClusterError("no trial finished its evaluation: nothing to compare")
    return spec.out


def first_line(err) -> str:
    cause = getattr(err, "cause", None)
    text = str(cause if isinstance(cause, BaseException) else err)
    return text.strip().splitlines()[-1] if text.strip() else type(err).__name__


def trials_table(spec: SweepSpec, rows) -> str:
    def f(v, fmt):
        return format(v, fmt) if isinstance(v, (int, float)) else "-"

    out = ["| run | model | seed | status | last val PSNR dB | at train s | test PSNR dB |", "|---|---|---|---|---|---|---|"]
    for model, seed, status, m, _ in rows:
        name = run_name(model, seed, seed == spec.seeds[0])
        out.append(f"| {name} | {model} | {seed} | {status} | {f(m.get('val_psnr'), '.2f')} | {f(m.get('wall_s'), '.1f')} | {f(m.get('test_psnr'), '.2f')} |")
    return "\n".join(out)
