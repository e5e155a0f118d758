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

Re-running a sweep into the same OUT continues it: beside each run the sweep keeps
`runs/NAME.trial.json` (the trial's settings and how far it got), and `plan_trial` decides from
it and the run folder what the trial does: nothing (evaluated with these settings), evaluate,
`xtask train --resume` (unfinished: stopped, crashed, killed), or train. A run folder the sweep
did not write, or one trained under other settings, is refused before anything starts unless
`--force`, which replaces such runs through `xtask train --force` (only the files a run is
made of). A refusal of `xtask` (exit status 1) ends its trial without a Tune retry; anything
else (an I/O error on the node, 74; a signal, 130; a crash) is retried and resumes.
"""

from __future__ import annotations

import collections
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
    force: bool = False
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
        force=getattr(args, "force", False),
        num_cpus=args.num_cpus,
        address=args.address,
        local_cpus=args.local_cpus,
    )


class JsonlTail:
    """The complete lines added to a JSON-lines file since the last call (from the start again
    if the file was replaced by another, e.g. renamed over it, or truncated). `skip_existing`:
    what the file holds now is not read."""

    def __init__(self, path: Path, skip_existing: bool = False):
        self.path, self.offset, self.file = path, 0, None
        if skip_existing:
            try:
                st = path.stat()
                self.offset, self.file = st.st_size, (st.st_dev, st.st_ino)
            except OSError:
                pass

    def read(self) -> list[dict]:
        try:
            with open(self.path, "rb") as f:
                st = os.fstat(f.fileno())
                if (st.st_dev, st.st_ino) != self.file:
                    self.offset, self.file = 0, (st.st_dev, st.st_ino)
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


#: What a trial did last, in `runs/NAME.trial.json` ("stage"): "training" from the moment its
#: `xtask train` starts, "trained" once it exited 0, "evaluated" once `xtask eval` did, "stopped"
#: when ASHA stopped it (written by the driver at the end of a sweep that ran to its end).
STAGES = ("training", "trained", "evaluated", "stopped")


def record_path(run: Path) -> Path:
    """The sweep's record of the trial whose run folder is `run`."""
    return run.with_name(f"{run.name}.trial.json")


def train_settings(spec: SweepSpec, model: str, seed: int) -> dict:
    """What a trial's run is trained from: a run recorded with other values is another trial's."""
    return {"dataset": str(spec.dataset), "model": model, "seed": seed, "time": spec.time, "steps": spec.steps}


def eval_settings(spec: SweepSpec) -> dict:
    """What a trial's evaluation depends on besides its run."""
    return {"eval_max_views": spec.eval_max_views}


def read_record(path: Path) -> Optional[dict]:
    """The trial record at `path`, or None when there is none (or it does not parse)."""
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and isinstance(rec.get("train"), dict) else None


def write_record(path: Path, train: dict, evaluation: Optional[dict], stage: str, refused: Optional[str] = None, replacing: bool = False) -> None:
    """Writes a trial record atomically (a temporary name, then a rename). `refused`: xtask's
    message when it refused the trial's last step; `replacing`: its `train --force` has not yet
    replaced the run that was in the folder (until then the folder is not the trial's)."""
    assert stage in STAGES, stage
    rec = {"train": train, "eval": evaluation, "stage": stage, "refused": refused, "replacing": replacing}
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(rec, indent=2) + "\n")
    os.replace(tmp, path)


def holds_run(run: Path) -> bool:
    """Whether `run` holds a training run (its config.json or a checkpoint), as `xtask train` sees it."""
    return (run / "config.json").is_file() or has_checkpoint(run)


def has_checkpoint(run: Path) -> bool:
    return any((run / "checkpoints").glob("step-*.ckpt"))


@dataclass(frozen=True)
class Plan:
    """What a trial does with what its run folder and record hold.

    action: "train" (`xtask train`; with `force`, `--force` replaces the run there), "resume"
    (`xtask train --resume`, then eval), "evaluate" (eval only), "done" (report the recorded
    results), "stopped" (ASHA stopped it: report its last validation), "refuse" (`why` says why).
    """

    action: str
    force: bool = False
    why: str = ""
    #: The run being replaced is not this trial's (another sweep's, a user's, other settings).
    other: bool = False


def differences(old: dict, new: dict) -> str:
    keys = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
    return ", ".join(f"{k} {old.get(k)!r} (now {new.get(k)!r})" for k in keys)


def plan_trial(run: Path, record: Optional[dict], train: dict, evaluation: dict, force: bool, asha: bool) -> Plan:
    """What the trial with run folder `run`, its record (`read_record`), and the settings of this
    sweep (`train_settings`, `eval_settings`) does; `force` and `asha` are the sweep's options.
    Pure: it reads the folder and decides, nothing more."""
    if record is not None and record.get("replacing"):
        record = None
    if record is None:
        if not holds_run(run):
            return Plan("train")
        if force:
            return Plan("train", force=True, why="a run this sweep did not write", other=True)
        return Plan(
            "refuse",
            why=f"{run} holds a training run this sweep did not write (no {record_path(run).name}): move it away, or pass --force to replace it",
        )
    if record["train"] != train:
        if not holds_run(run):
            return Plan("train")
        if force:
            return Plan("train", force=True, why=f"trained with other settings: {differences(record['train'], train)}", other=True)
        return Plan(
            "refuse",
            why=f"{run} was trained with other settings: {differences(record['train'], train)}; pass --force to train it again, or give another --out",
        )
    if not holds_run(run):
        return Plan("train")
    stage = record.get("stage")
    if stage == "evaluated" and record.get("eval") == evaluation and (run / "report.json").is_file():
        return Plan("done")
    if stage in ("trained", "evaluated"):
        return Plan("evaluate")
    if stage == "stopped" and asha:
        return Plan("stopped")
    if has_checkpoint(run):
        return Plan("resume")
    # Killed before its first checkpoint: nothing to resume, and the run is this trial's own.
    return Plan("train", force=True, why="stopped before its first checkpoint")


def plans(spec: SweepSpec) -> dict[tuple[str, int], Plan]:
    """Every trial's plan, in sweep order."""
    out = {}
    for model in spec.models:
        for seed in spec.seeds:
            run = spec.run_dir(model, seed)
            out[(model, seed)] = plan_trial(run, read_record(record_path(run)), train_settings(spec, model, seed), eval_settings(spec), spec.force, spec.asha)
    return out


def check_plans(spec: SweepSpec) -> dict[tuple[str, int], Plan]:
    """The plans, or one ClusterError naming every trial whose folder this sweep must not touch."""
    ps = plans(spec)
    refused = [p.why for p in ps.values() if p.action == "refuse"]
    if refused:
        raise ClusterError("\n".join(refused))
    return ps


def last_val(run: Path) -> Optional[dict]:
    """The Tune result of the run's last validation line, if any."""
    vals = [r for r in JsonlTail(run / "metrics.jsonl").read() if r.get("val_psnr") is not None]
    return val_metrics(vals[-1]) if vals else None


def train_command(spec: SweepSpec, model: str, seed: int, run: Path, plan: Plan, log) -> list[str]:
    """The `xtask train` command of a trial's plan ("train" or "resume")."""
    if plan.action == "resume":
        return [spec.xtask, "train", "--out", str(run), "--resume"]
    runs = run.parent
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
    if plan.force:
        cmd.append("--force")
    return cmd


def file_id(path: Path) -> Optional[tuple]:
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)


def train_run(spec: SweepSpec, cmd: list[str], run: Path, log_path: Path, logf, report, fresh: bool, on_replaced=None) -> Optional[dict]:
    """Runs `xtask train` (`cmd`), handing each validation line of the run's metrics.jsonl to
    `report` as it appears, once each and in training-time order (a resumed run's earlier ones
    first); returns the last. `fresh`: the lines there now are an old run's, not reported.
    `on_replaced` is called once the run's config.json was written anew (the old run is gone)."""
    config_before = file_id(run / "config.json")
    proc = subprocess.Popen(
        cmd,
        cwd=cwd_of(spec),
        env=xt.with_threads(None, spec.threads()),
        stdin=subprocess.DEVNULL,
        stdout=logf,
        stderr=subprocess.STDOUT,
        preexec_fn=xt.child_preexec(),
    )
    tail = JsonlTail(run / "metrics.jsonl", skip_existing=fresh)
    last = None
    try:
        while True:
            rc = proc.poll()
            for rec in tail.read():
                if rec.get("val_psnr") is not None:
                    m = val_metrics(rec)
                    if last is None or m["wall_s"] > last["wall_s"]:
                        last = m
                        report(last)
            if rc is not None:
                break
            time.sleep(POLL_S)
    finally:
        xt.stop(proc)
        if on_replaced and file_id(run / "config.json") not in (None, config_before):
            on_replaced()
    if rc != 0:
        raise xt.failure(f"training {run.name} (see {log_path})", rc, log_tail(log_path))
    return last


def trial(config: dict, spec: SweepSpec) -> None:
    """A Ray Tune trial: what `plan_trial` says (train or resume, with validations reported as
    they appear; evaluate; report). An `xtask` refusal is recorded and ends the trial without an
    error, so Tune does not retry what would be refused again; any other failure raises."""
    from ray import tune

    model, seed = config["model"], int(config["seed"])
    run = spec.run_dir(model, seed)
    runs = run.parent
    runs.mkdir(parents=True, exist_ok=True)
    rec_path = record_path(run)
    train, evaluation = train_settings(spec, model, seed), eval_settings(spec)
    record = read_record(rec_path)
    plan = plan_trial(run, record, train, evaluation, spec.force, spec.asha)
    if plan.action == "refuse":
        raise ClusterError(plan.why)
    log_path = runs / f"{run.name}.log"
    last = last_val(run) if plan.action in ("evaluate", "done", "stopped") else None
    with open(log_path, "a") as logf:

        def log(line: str) -> None:
            logf.write(line + "\n")
            logf.flush()

        log(f"== {plan.action}" + (f" (replacing the run: {plan.why})" if plan.force else ""))
        stage = (record or {}).get("stage", "training")
        try:
            if plan.action in ("train", "resume"):
                stage = "training"
                # Written first: from here on a crash leaves a run that the next attempt resumes
                # (or, while `replacing`, a folder that is still not this trial's).
                write_record(rec_path, train, None, stage, replacing=plan.other)

                def replaced() -> None:
                    write_record(rec_path, train, None, "training")

                cmd = train_command(spec, model, seed, run, plan, log)
                log("$ " + " ".join(cmd))
                try:
                    last = train_run(spec, cmd, run, log_path, logf, tune.report, fresh=plan.action == "train", on_replaced=replaced) or last
                except xt.XtaskRefused:
                    if not (plan.action == "resume" and spec.force):
                        raise
                    # --force: a run that cannot be continued (its dataset changed) is replaced.
                    cmd = train_command(spec, model, seed, run, Plan("train", force=True), log)
                    log("$ " + " ".join(cmd))
                    last = train_run(spec, cmd, run, log_path, logf, tune.report, fresh=True)
                stage = "trained"
                write_record(rec_path, train, None, stage)
            if plan.action == "stopped":
                if last:
                    tune.report(last)
                return
            if plan.action != "done":
                cmd = [spec.xtask, "eval", str(run)]
                if spec.eval_max_views:
                    cmd += ["--max-views", str(spec.eval_max_views)]
                log("$ " + " ".join(cmd))
                xt.run(cmd, f"evaluating {run.name} (see {log_path})", cwd=cwd_of(spec), env=xt.with_threads(None, spec.threads()), on_line=log)
                write_record(rec_path, train, evaluation, "evaluated")
        except xt.XtaskRefused as e:
            log(f"refused: {e}")
            replacing = bool((read_record(rec_path) or {}).get("replacing"))
            write_record(rec_path, train, None, stage if stage in STAGES else "training", refused=str(e), replacing=replacing)
            return
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
    todo = check_plans(spec)
    counts = collections.Counter(p.action for p in todo.values())
    print(f"[cluster] {len(todo)} trials: " + ", ".join(f"{n} {PLAN_WORDS[a]}" for a, n in counts.items()), file=sys.stderr, flush=True)
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
        # Fewer ended trials than trials: the sweep was interrupted, and its unfinished trials
        # are not ASHA's to mark.
        ran_to_end = results.num_terminated + results.num_errors == len(results)
        rows = []
        for r in results:
            m = r.metrics or {}
            model, seed = r.config["model"], int(r.config["seed"])
            run = spec.run_dir(model, seed)
            rec = read_record(record_path(run))
            status, err = trial_status(m, r.error, rec), r.error
            if status == "refused":
                err = rec["refused"]
            elif status == "stopped early" and ran_to_end and rec is not None and rec.get("stage") == "training":
                write_record(record_path(run), rec["train"], None, "stopped")
            rows.append((model, seed, status, m, err))
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
    failed = [(model, seed, status, err) for model, seed, status, _, err in rows if status in ("failed", "refused")]
    if failed:
        lines = "".join(f"\n  {run_name(m, s, s == spec.seeds[0])} ({status}): {first_line(err)}" for m, s, status, err in failed)
        raise ClusterError(f"{len(failed)} of {len(rows)} trials failed or were refused (logs in {spec.out / 'runs'}):{lines}")
    if not evaluated:
        raise ClusterError("no trial finished its evaluation: nothing to compare")
    return spec.out


#: How the driver's summary names each plan.
PLAN_WORDS = {"train": "to train", "resume": "to resume", "evaluate": "to evaluate", "done": "evaluated already (kept)", "stopped": "stopped by ASHA earlier (kept)"}


def trial_status(metrics: dict, error, record: Optional[dict]) -> str:
    """A finished trial's row status: evaluated, failed (an error Tune saw), refused (xtask
    refused it; the trial ended without an error so that Tune would not retry it), or stopped
    early (ASHA)."""
    if metrics.get("evaluated"):
        return "evaluated"
    if error:
        return "failed"
    if record is not None and record.get("refused"):
        return "refused"
    return "stopped early"


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
