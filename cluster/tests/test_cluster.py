"""The cluster drivers' own logic, without Ray or the xtask binary: argument splitting, durations,
the metrics tail, exit-status classification, shard writing and the refusals that must come
before anything is written. Each test takes well under a second."""

from __future__ import annotations

import io
import json
import os
import pickle
import shutil
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
import types
import unittest
from contextlib import redirect_stderr
from pathlib import Path
from unittest import mock

from cluster import ClusterError
from cluster import __main__ as cli
from cluster import raysession, render, sweep
from cluster import xtask as xt

REPO = Path(__file__).resolve().parents[2]


def quiet_main(argv: list[str]) -> tuple[int, str]:
    """`python -m cluster ARGV` in this process: (exit status, stderr)."""
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main(argv)
    return rc, err.getvalue()


class SplitRenderArgs(unittest.TestCase):
    def split(self, *argv):
        return cli.split_render_args(cli.parser(), list(argv))

    def test_unknown_options_go_to_xtask_with_their_values(self):
        ours, theirs = self.split("--preset", "quick", "tabletop", "--out", "/d", "--shards", "3", "--res=32", "--force", "--spp", "4")
        self.assertEqual(ours, ["tabletop", "--out", "/d", "--shards", "3"])
        self.assertEqual(theirs, ["--preset", "quick", "--res=32", "--force", "--spp", "4"])

    def test_driver_switches_take_no_value(self):
        ours, theirs = self.split("--shared-storage", "tabletop", "--keep-shards", "--out", "/d", "--shards", "2", "--address", "h:1")
        self.assertEqual(ours, ["--shared-storage", "tabletop", "--keep-shards", "--out", "/d", "--shards", "2", "--address", "h:1"])
        self.assertEqual(theirs, [])

    def test_equals_form_of_a_driver_option(self):
        ours, theirs = self.split("tabletop", "--out=/d", "--shards=2", "--train", "4")
        self.assertEqual(ours, ["tabletop", "--out=/d", "--shards=2"])
        self.assertEqual(theirs, ["--train", "4"])


class Durations(unittest.TestCase):
    def test_forms(self):
        for text, seconds in [("90s", 90), ("90", 90), ("5m", 300), ("5min", 300), ("1.5m", 90), ("1h", 3600), (" 20s ", 20), (".5s", 0.5)]:
            self.assertEqual(sweep.parse_duration(text), seconds, text)

    def test_bad(self):
        for text in ["", "0s", "-1s", "5x", "m", "1e3s", "5 m s"]:
            with self.assertRaises(ClusterError, msg=text):
                sweep.parse_duration(text)

    def test_comma_list(self):
        self.assertEqual(sweep.comma_list(" auto, fast-small,,paper ,"), ["auto", "fast-small", "paper"])


class Addresses(unittest.TestCase):
    def test_host_port(self):
        self.assertEqual(raysession.host_port("10.0.0.1:6379"), ("10.0.0.1", 6379))
        self.assertEqual(raysession.host_port("ray://head:10001"), ("head", 10001))
        self.assertEqual(raysession.host_port("[::1]:6379"), ("::1", 6379))
        self.assertEqual(raysession.host_port(":6379"), ("127.0.0.1", 6379))
        for a in ["auto", "local", "head", "head:port"]:
            self.assertIsNone(raysession.host_port(a), a)

    def test_closed_port_is_a_clear_error_at_once(self):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        t0 = time.monotonic()
        with self.assertRaisesRegex(ClusterError, rf"cannot reach the Ray cluster at 127.0.0.1:{port}.*ray start --head --port={port}"):
            raysession.check_reachable(f"127.0.0.1:{port}")
        with self.assertRaisesRegex(ClusterError, "ray-client-server-port"):
            raysession.check_reachable(f"ray://127.0.0.1:{port}")
        self.assertLess(time.monotonic() - t0, 5)

    def test_listening_port_passes(self):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            s.listen(1)
            raysession.check_reachable(f"127.0.0.1:{s.getsockname()[1]}")

    def test_deadline_ends_the_process_with_status_1(self):
        code = textwrap.dedent(
            """
            import time
            from cluster.raysession import deadline
            with deadline(0.3, "the head did not answer"):
                time.sleep(30)
            """
        )
        t0 = time.monotonic()
        p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=20)
        self.assertEqual(p.returncode, 1)
        self.assertIn("error: the head did not answer", p.stderr)
        self.assertLess(time.monotonic() - t0, 10)

    def test_deadline_not_reached(self):
        with raysession.deadline(5, "never"):
            pass


class Tail(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.path = Path(self.dir.name) / "metrics.jsonl"

    def tearDown(self):
        self.dir.cleanup()

    def append(self, text: str):
        with open(self.path, "a") as f:
            f.write(text)

    def test_complete_lines_once_each(self):
        tail = sweep.JsonlTail(self.path)
        self.assertEqual(tail.read(), [], "no file yet")
        self.append('{"step": 1}\n{"step": 2')
        self.assertEqual(tail.read(), [{"step": 1}])
        self.assertEqual(tail.read(), [])
        self.append(', "val_psnr": 20.5}\nnot json\n{"step": 3}\n')
        self.assertEqual(tail.read(), [{"step": 2, "val_psnr": 20.5}, {"step": 3}])
        self.assertEqual(tail.read(), [])

    def test_replaced_by_a_longer_file_reads_from_the_start(self):
        tail = sweep.JsonlTail(self.path)
        self.append('{"step": 1}\n')
        self.assertEqual(len(tail.read()), 1)
        other = self.path.with_name("other")
        other.write_text('{"step": 7}\n{"step": 8}\n')
        os.replace(other, self.path)
        self.assertEqual(tail.read(), [{"step": 7}, {"step": 8}])

    def test_skip_existing(self):
        self.append('{"step": 1}\n')
        tail = sweep.JsonlTail(self.path, skip_existing=True)
        self.assertEqual(tail.read(), [])
        self.append('{"step": 2}\n')
        self.assertEqual(tail.read(), [{"step": 2}])

    def test_replaced_by_a_shorter_file_reads_from_the_start(self):
        tail = sweep.JsonlTail(self.path)
        self.append('{"step": 1}\n{"step": 2}\n')
        self.assertEqual(len(tail.read()), 2)
        self.path.write_text('{"step": 9}\n')
        self.assertEqual(tail.read(), [{"step": 9}])

    def test_val_metrics(self):
        self.assertEqual(
            sweep.val_metrics({"val_psnr": 21, "wall_s": 3.5, "step": 40, "val_depth_mae": 0.1, "eval_s": 2}),
            {"val_psnr": 21.0, "wall_s": 3.5, "step": 40, "val_depth_mae": 0.1},
        )
        self.assertEqual(sweep.val_metrics({"val_psnr": 21, "val_depth_mae": None}), {"val_psnr": 21.0, "wall_s": 0.0, "step": 0})


class RunningXtask(unittest.TestCase):
    def test_lines_and_success(self):
        seen = []
        lines = xt.run(["/bin/sh", "-c", "echo one; echo two >&2"], "sh", on_line=seen.append)
        self.assertEqual(sorted(lines), ["one", "two"])
        self.assertEqual(seen, lines)

    def test_refusals_are_not_retried_crashes_are(self):
        with self.assertRaises(xt.XtaskRefused) as c:
            xt.run(["/bin/sh", "-c", "echo 'error: scene nope'; exit 1"], "shard 0/2")
        self.assertIn("shard 0/2 exited with status 1; its last output:\n    error: scene nope", str(c.exception))
        with self.assertRaises(xt.XtaskRefused):
            xt.run(["/bin/sh", "-c", "exit 2"], "usage")
        with self.assertRaises(xt.XtaskFailed) as c:
            xt.run(["/bin/sh", "-c", "kill -9 $$"], "killed")
        self.assertIn("was killed by signal 9", str(c.exception))
        with self.assertRaises(xt.XtaskFailed):
            xt.run(["/bin/sh", "-c", "exit 101"], "panic")
        with self.assertRaises(xt.XtaskFailed) as c:
            xt.run(["/bin/sh", "-c", "exit 74"], "disk full")
        self.assertIn("exited with status 74 (an I/O error on this node", str(c.exception))
        with self.assertRaises(xt.XtaskFailed) as c:
            xt.run(["/bin/sh", "-c", "exit 130"], "stopped")
        self.assertIn("exited with status 130 (stopped by a signal; its work is saved)", str(c.exception))
        with self.assertRaises(xt.XtaskFailed) as c:
            xt.run(["/no/such/xtask", "render"], "missing")
        self.assertEqual(c.exception.returncode, 127)

    def test_errors_survive_pickling(self):
        # Ray sends a task's exception to the driver pickled.
        for e in [xt.XtaskFailed("w", -9, ["a"]), xt.XtaskRefused("w", 1, ["b"])]:
            back = pickle.loads(pickle.dumps(e))
            self.assertIs(type(back), type(e))
            self.assertEqual((back.what, back.returncode, back.tail, str(back)), (e.what, e.returncode, e.tail, str(e)))

    def test_child_dies_with_its_parent(self):
        # A killed Ray worker must take its xtask with it.
        code = "from cluster import xtask as xt; xt.run(['/bin/sh', '-c', 'echo $$; exec sleep 60'], 'sleep', on_line=lambda l: print(l, flush=True))"
        parent = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
        child = int(parent.stdout.readline())
        parent.kill()
        parent.wait()
        for _ in range(50):
            try:
                os.kill(child, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        else:
            os.kill(child, 9)
            self.fail("the child outlived its parent")

    def test_child_gets_default_ctrl_c(self):
        # A Ray worker ignores SIGINT; xtask must still be able to install its Ctrl-C handler.
        code = "import signal; from cluster import xtask as xt; signal.signal(signal.SIGINT, signal.SIG_IGN); xt.run(['/bin/sh', '-c', 'grep SigIgn /proc/self/status'], 'sh', on_line=print)"
        out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True).stdout
        ignored = int(out.split()[-1], 16)
        self.assertFalse(ignored & (1 << (2 - 1)), f"SIGINT still ignored in the child: {out}")

    def test_find_xtask_takes_the_given_path(self):
        self.assertEqual(xt.find_xtask("/opt/nodes/xtask"), ("/opt/nodes/xtask", "--xtask"))

    def test_threads_and_flags(self):
        self.assertEqual(xt.with_threads({"A": "1"}, 3), {"A": "1", "RAYON_NUM_THREADS": "3"})
        self.assertTrue(xt.has_flag(["--threads=2"], "--threads"))
        self.assertTrue(xt.has_flag(["--out", "x"], "--out"))
        self.assertFalse(xt.has_flag(["--output"], "--out"))


class Shards(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.root = Path(self.dir.name)

    def tearDown(self):
        self.dir.cleanup()

    def job(self, **kw):
        return render.RenderJob(scene="tabletop", out=self.root / "ds", shards=3, xtask="/no/xtask", **kw)

    def test_folders(self):
        job = self.job()
        self.assertEqual(job.shard_dir(2), self.root / "ds.shards" / "2")
        self.assertEqual(self.job(num_cpus=0.5).threads(), 1)

    def test_write_shard_through_part_folder(self):
        folder = self.root / "ds.shards" / "0"
        render.write_shard(folder, {"shard.json": b"{}", "train/r_0.png": b"png"})
        self.assertEqual((folder / "train" / "r_0.png").read_bytes(), b"png")
        self.assertFalse(folder.with_name("0.part").exists())
        render.write_shard(folder, {"shard.json": b"[]"})
        self.assertEqual(sorted(p.name for p in folder.rglob("*")), ["shard.json"], "an older shard is replaced whole")

    def test_dead_workers_tmp_folders_are_removed(self):
        dead = subprocess.Popen(["true"])
        dead.wait()
        gone = self.root / f"{render.TMP_PREFIX}{dead.pid}-1-abc"
        live = self.root / f"{render.TMP_PREFIX}{os.getpid()}-2-def"
        other = self.root / "nerf-gt-shard-x"
        for d in (gone, live, other):
            (d / "shard").mkdir(parents=True)
        render.remove_dead_tmp(self.root)
        self.assertEqual(sorted(p.name for p in self.root.iterdir()), sorted([live.name, other.name]))

    def test_write_shard_refuses_paths_outside(self):
        with self.assertRaises(ClusterError):
            render.write_shard(self.root / "s" / "0", {"../../evil": b"x"})
        self.assertFalse((self.root / "evil").exists())

    def test_refusals_before_anything_is_written(self):
        for kw, msg in [
            (dict(shards=0), "--shards 0"),
            (dict(render_args=["--shard", "0/2"]), "--shard is set by the driver"),
            (dict(render_args=["--out=/x"]), "--out is set by the driver"),
        ]:
            job = self.job()
            for k, v in kw.items():
                setattr(job, k, v)
            with self.assertRaisesRegex(ClusterError, msg):
                render.run(job)
        (self.root / "ds").mkdir()
        (self.root / "ds" / "x").write_text("")
        with self.assertRaisesRegex(ClusterError, "exists and is not an empty folder"):
            render.run(self.job())
        self.assertEqual(sorted(p.name for p in self.root.iterdir()), ["ds"])

    def test_shard_failure_message(self):
        class RayTaskError(Exception):
            def __init__(self, cause):
                super().__init__("traceback ...")
                self.cause = cause

        refused = RayTaskError(xt.XtaskRefused("shard 1/3", 1, ["error: no scene"]))
        self.assertEqual(render.shard_failure(self.job(), 1, refused), "shard 1/3 exited with status 1; its last output:\n    error: no scene")
        crashed = RayTaskError(xt.XtaskFailed("shard 1/3", -9, []))
        self.assertEqual(render.shard_failure(self.job(), 1, crashed), "shard 1/3 failed after up to 3 retries: shard 1/3 was killed by signal 9")
        self.assertIn("WorkerCrashedError", render.shard_failure(self.job(), 2, type("WorkerCrashedError", (Exception,), {})("lost")))


class SweepPlans(unittest.TestCase):
    """What a re-run of a sweep does with each trial's run folder and record."""

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.root = Path(self.dir.name)
        self.spec = sweep.SweepSpec(dataset=self.root / "ds", models=["fast"], seeds=[0], out=self.root / "out", xtask="/no/xtask", steps=30)
        self.run = self.spec.run_dir("fast", 0)
        self.train = sweep.train_settings(self.spec, "fast", 0)
        self.eval = sweep.eval_settings(self.spec)

    def tearDown(self):
        self.dir.cleanup()

    def make_run(self, checkpoint=True, report=False):
        (self.run / "checkpoints").mkdir(parents=True, exist_ok=True)
        (self.run / "config.json").write_text("{}")
        if checkpoint:
            (self.run / "checkpoints" / "step-30.ckpt").write_bytes(b"x")
        if report:
            (self.run / "report.json").write_text("{}")

    def record(self, stage, train=None, evaluation=None, **kw):
        sweep.write_record(sweep.record_path(self.run), train or self.train, evaluation, stage, **kw)

    def plan(self, force=False, asha=False):
        return sweep.plan_trial(self.run, sweep.read_record(sweep.record_path(self.run)), self.train, self.eval, force, asha)

    def test_a_new_trial_trains(self):
        self.assertEqual(self.plan(), sweep.Plan("train"))
        self.run.mkdir(parents=True)
        self.assertEqual(self.plan(), sweep.Plan("train"), "an empty folder holds no run")

    def test_an_evaluated_trial_is_kept_and_evaluated_again_only_for_other_eval_settings(self):
        self.make_run(report=True)
        self.record("evaluated", evaluation=self.eval)
        self.assertEqual(self.plan().action, "done")
        self.assertEqual(self.plan(force=True).action, "done", "--force replaces only what cannot be continued")
        self.record("evaluated", evaluation={"eval_max_views": 3})
        self.assertEqual(self.plan().action, "evaluate")
        self.record("trained")
        self.assertEqual(self.plan().action, "evaluate")

    def test_an_unfinished_trial_resumes(self):
        self.make_run()
        self.record("training")
        self.assertEqual(self.plan(), sweep.Plan("resume"))
        self.record("training", refused="error: something")
        self.assertEqual(self.plan(), sweep.Plan("resume"), "a refusal is tried again on a re-run")

    def test_a_trial_killed_before_its_first_checkpoint_trains_again(self):
        self.make_run(checkpoint=False)
        self.record("training")
        plan = self.plan()
        self.assertEqual((plan.action, plan.force, plan.other), ("train", True, False))

    def test_asha_decisions_stand_while_asha_is_on(self):
        self.make_run()
        self.record("stopped")
        self.assertEqual(self.plan(asha=True).action, "stopped")
        self.assertEqual(self.plan(asha=False).action, "resume")

    def test_a_run_the_sweep_did_not_write_is_refused_unless_forced(self):
        self.make_run()
        plan = self.plan()
        self.assertEqual(plan.action, "refuse")
        self.assertIn(str(self.run), plan.why)
        self.assertIn("--force", plan.why)
        plan = self.plan(force=True)
        self.assertEqual((plan.action, plan.force, plan.other), ("train", True, True))
        # A replacement that did not happen yet leaves the folder someone else's.
        self.record("training", replacing=True)
        self.assertEqual(self.plan().action, "refuse")

    def test_a_run_of_other_settings_is_refused_naming_them_unless_forced(self):
        self.make_run(report=True)
        self.record("evaluated", train={**self.train, "steps": 10}, evaluation=self.eval)
        plan = self.plan()
        self.assertEqual(plan.action, "refuse")
        self.assertIn("steps 10 (now 30)", plan.why)
        plan = self.plan(force=True)
        self.assertEqual((plan.action, plan.force, plan.other), ("train", True, True))
        shutil.rmtree(self.run)
        self.assertEqual(self.plan(), sweep.Plan("train"), "nothing there to lose")

    def test_check_plans_names_every_refusal_and_touches_nothing(self):
        spec = sweep.SweepSpec(dataset=self.root / "ds", models=["fast", "auto"], seeds=[0, 1], out=self.root / "out", xtask="/no/xtask", steps=30)
        for model in spec.models:
            (spec.run_dir(model, 1) / "checkpoints").mkdir(parents=True)
            (spec.run_dir(model, 1) / "config.json").write_text("{}")
        before = sorted(p.relative_to(self.root) for p in self.root.rglob("*"))
        with self.assertRaises(ClusterError) as c:
            sweep.check_plans(spec)
        self.assertIn("fast-seed1", str(c.exception))
        self.assertIn("auto-seed1", str(c.exception))
        self.assertEqual(sorted(p.relative_to(self.root) for p in self.root.rglob("*")), before)
        spec.force = True
        self.assertEqual([p.action for p in sweep.check_plans(spec).values()], ["train"] * 4)

    def test_trial_status(self):
        self.assertEqual(sweep.trial_status({"evaluated": True}, None, None), "evaluated")
        self.assertEqual(sweep.trial_status({}, RuntimeError("x"), None), "failed")
        self.assertEqual(sweep.trial_status({}, None, {"refused": "error: no"}), "refused")
        self.assertEqual(sweep.trial_status({"val_psnr": 20}, None, {"refused": None}), "stopped early")


#: A stand-in for the xtask binary: logs its arguments, exits with FAKE_XTASK_EXIT if set, and
#: otherwise writes what `train` (a config, a checkpoint, one validation line per call) and
#: `eval` (report.json) write.
FAKE_XTASK = """#!{python}
import json, os, sys
from pathlib import Path
args = sys.argv[1:]
with open(os.environ["FAKE_XTASK_LOG"], "a") as f:
    f.write(" ".join(args) + "\\n")
code = int(os.environ.get("FAKE_XTASK_EXIT", "0"))
if code:
    print("error: fake refusal")
    sys.exit(code)
if args[0] == "train":
    run = Path(args[args.index("--out") + 1])
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    if "--resume" not in args:
        (run / "config.json").write_text("{{}}")
        (run / "metrics.jsonl").write_text("")
    n = len((run / "metrics.jsonl").read_text().splitlines())
    with open(run / "metrics.jsonl", "a") as f:
        f.write(json.dumps({{"step": 10 * (n + 1), "wall_s": n + 1.0, "val_psnr": 20.0 + n}}) + "\\n")
    (run / "checkpoints" / f"step-{{10 * (n + 1)}}.ckpt").write_bytes(b"x")
elif args[0] == "eval":
    Path(args[1], "report.json").write_text(json.dumps({{"final_psnr": 21.5, "train_steps": 10}}))
"""


class SweepTrials(unittest.TestCase):
    """`sweep.trial` itself, with a stand-in for Ray Tune's `report` and for xtask."""

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.root = Path(self.dir.name)
        self.xtask = self.root / "xtask"
        self.xtask.write_text(FAKE_XTASK.format(python=sys.executable))
        self.xtask.chmod(0o755)
        self.calls = self.root / "calls.txt"
        self.spec = sweep.SweepSpec(dataset=self.root / "ds", models=["fast"], seeds=[0], out=self.root / "out", xtask=str(self.xtask), steps=10)
        self.run = self.spec.run_dir("fast", 0)

    def tearDown(self):
        self.dir.cleanup()

    def trial(self, exit_code=0):
        """Runs the trial; returns (what it reported to Tune, the xtask calls it made)."""
        reports = []
        fake_ray = types.ModuleType("ray")
        fake_ray.tune = types.SimpleNamespace(report=reports.append)
        self.calls.write_text("")
        env = {"FAKE_XTASK_LOG": str(self.calls), "FAKE_XTASK_EXIT": str(exit_code)}
        with mock.patch.dict(sys.modules, {"ray": fake_ray}), mock.patch.dict(os.environ, env):
            sweep.trial({"model": "fast", "seed": 0}, self.spec)
        self.full_calls = self.calls.read_text().splitlines()
        return reports, [c.split()[0:2] for c in self.full_calls]

    def record(self):
        return sweep.read_record(sweep.record_path(self.run))

    def test_a_rerun_keeps_finished_trials_and_resumes_unfinished_ones(self):
        reports, calls = self.trial()
        self.assertEqual(calls, [["train", str(self.spec.dataset)], ["eval", str(self.run)]])
        self.assertEqual(reports[-1]["test_psnr"], 21.5)
        self.assertEqual(self.record()["stage"], "evaluated")

        # Finished: nothing runs, the results are reported again, nothing is removed.
        before = (self.run / "metrics.jsonl").read_text()
        reports, calls = self.trial()
        self.assertEqual(calls, [])
        self.assertEqual((reports[-1]["evaluated"], reports[-1]["val_psnr"]), (True, 20.0))
        self.assertEqual((self.run / "metrics.jsonl").read_text(), before)

        # Killed while training (a node fault, Tune's retry, a Ctrl-C of the driver): resumed.
        (self.run / "report.json").unlink()
        sweep.write_record(sweep.record_path(self.run), self.record()["train"], None, "training")
        reports, calls = self.trial()
        self.assertEqual(calls, [["train", "--out"], ["eval", str(self.run)]])
        self.assertEqual([r["val_psnr"] for r in reports if not r.get("evaluated")], [20.0, 21.0], "the earlier validation first, once")
        self.assertEqual(len((self.run / "metrics.jsonl").read_text().splitlines()), 2, "the history is kept")

    def test_a_refusal_ends_the_trial_without_an_error_and_is_recorded(self):
        reports, calls = self.trial(exit_code=1)
        self.assertEqual((reports, calls), ([], [["train", str(self.spec.dataset)]]))
        rec = self.record()
        self.assertIn("error: fake refusal", rec["refused"])
        self.assertEqual(sweep.trial_status({}, None, rec), "refused")

    def test_force_replaces_a_run_it_did_not_write_only_once_xtask_did(self):
        (self.run / "checkpoints").mkdir(parents=True)
        (self.run / "config.json").write_text("{}")
        (self.run / "checkpoints" / "step-5.ckpt").write_bytes(b"x")
        (self.run / "notes.txt").write_text("mine")
        (self.run / "metrics.jsonl").write_text('{"step": 500, "wall_s": 99.0, "val_psnr": 30.0}\n')
        self.spec.force = True
        reports, calls = self.trial(exit_code=1)
        self.assertEqual(calls, [["train", str(self.spec.dataset)]])
        self.assertTrue(self.full_calls[0].endswith(" --force"), self.full_calls)
        self.spec.force = False
        self.assertEqual(sweep.plans(self.spec)[("fast", 0)].action, "refuse", "xtask refused: the folder is still someone else's")
        self.spec.force = True
        reports, calls = self.trial()
        self.assertEqual(calls, [["train", str(self.spec.dataset)], ["eval", str(self.run)]])
        self.assertEqual(reports[-1]["val_psnr"], 20.0, "the old run's lines are not reported")
        self.assertEqual((self.run / "notes.txt").read_text(), "mine", "the sweep removes nothing itself")
        self.spec.force = False
        self.assertEqual(sweep.plans(self.spec)[("fast", 0)].action, "done")

    def test_node_faults_raise_for_tunes_retry(self):
        for code in (74, 130, 101):
            with self.assertRaises(xt.XtaskFailed, msg=code):
                self.trial(exit_code=code)
            self.assertIsNone(self.record()["refused"])


class CommandLine(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.root = Path(self.dir.name)

    def tearDown(self):
        self.dir.cleanup()

    def test_render_refusals_exit_1_nothing_written(self):
        out = str(self.root / "ds")
        for extra in (["--shards", "0"], ["--shards", "2", "--shard", "1/2"]):
            rc, err = quiet_main(["render", "tabletop", "--out", out, "--preset", "quick", "--xtask", "/no/xtask", *extra])
            self.assertEqual(rc, 1, err)
            self.assertRegex(err, r"error: --shard")
        self.assertEqual(list(self.root.iterdir()), [])

    def test_counts_ray_would_misread(self):
        out = str(self.root / "ds")
        for extra, msg in [
            (["--num-cpus", "0"], "--num-cpus 0: give a positive"),
            (["--num-cpus", "-1"], "--num-cpus -1"),
            (["--local-cpus", "0"], "--local-cpus 0"),
            (["--max-retries", "-1"], "--max-retries -1: give at least 0"),
        ]:
            rc, err = quiet_main(["render", "tabletop", "--out", out, "--shards", "2", "--xtask", "/no/xtask", *extra])
            self.assertEqual(rc, 1, extra)
            self.assertIn(msg, err)
        rc, err = quiet_main(["sweep", str(self.root), "--steps", "5", "--eval-max-views", "0", "--xtask", "/no/xtask"])
        self.assertEqual((rc, "--eval-max-views 0: give at least 1" in err), (1, True), err)
        self.assertEqual(list(self.root.iterdir()), [])

    def test_render_unreachable_address(self):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        rc, err = quiet_main(["render", "tabletop", "--out", str(self.root / "ds"), "--shards", "2", "--xtask", "/no/xtask", "--address", f"127.0.0.1:{port}"])
        if "Ray is not installed" in err:
            self.skipTest("no ray in this Python")
        self.assertEqual(rc, 1)
        self.assertIn(f"cannot reach the Ray cluster at 127.0.0.1:{port}", err)
        self.assertEqual(list(self.root.iterdir()), [])

    def dataset(self) -> Path:
        ds = self.root / "ds"
        ds.mkdir()
        (ds / "transforms_train.json").write_text(json.dumps({"frames": []}))
        return ds

    def test_sweep_refusals(self):
        ds = str(self.dataset())
        cases = [
            ([str(self.root / "none"), "--steps", "5"], "no such dataset folder"),
            ([str(self.root), "--steps", "5"], "not a dataset"),
            ([ds, "--models", "fast,bogus", "--steps", "5"], "unknown model 'bogus'"),
            ([ds, "--models", "fast,fast", "--steps", "5"], "give each model once"),
            ([ds, "--seeds", "0,x", "--steps", "5"], "comma-separated integers"),
            ([ds, "--seeds", "1,1", "--steps", "5"], "give each seed"),
            ([ds, "--steps", "0"], "--steps must be positive"),
            ([ds, "--time", "5x"], "bad duration '5x'"),
            ([ds, "--steps", "5", "--asha"], "--asha needs --time"),
        ]
        for argv, msg in cases:
            rc, err = quiet_main(["sweep", *argv, "--xtask", "/no/xtask", "--out", str(self.root / "sweep")])
            self.assertEqual(rc, 1, argv)
            self.assertIn(msg, err, argv)
        self.assertFalse((self.root / "sweep").exists())

    def test_sweep_spec(self):
        ds = self.dataset()
        args = cli.parser().parse_args(["sweep", str(ds), "--models", "auto,fast-small", "--seeds", "0,2", "--time", "1.5m", "--xtask", "/no/xtask", "--out", str(self.root / "s")])
        with redirect_stderr(io.StringIO()):
            spec = sweep.spec_from_args(args)
        self.assertEqual((spec.models, spec.seeds, spec.time, spec.steps), (["auto", "fast-small"], [0, 2], "90s", None))
        self.assertEqual(spec.run_dir("fast-small", 0), self.root / "s" / "runs" / "fast-small")
        self.assertEqual(spec.run_dir("auto", 2), self.root / "s" / "runs" / "auto-seed2")
        args = cli.parser().parse_args(["sweep", str(ds), "--steps", "30", "--xtask", "/no/xtask"])
        with redirect_stderr(io.StringIO()):
            self.assertIsNone(sweep.spec_from_args(args).time, "--steps alone: no time budget")

    def test_trials_table(self):
        spec = sweep.SweepSpec(dataset=Path("/d"), models=["fast"], seeds=[0, 1], out=Path("/o"), xtask="/x")
        table = sweep.trials_table(spec, [("fast", 0, "evaluated", {"val_psnr": 20.123, "wall_s": 12.0, "test_psnr": 21.0}, None), ("fast", 1, "failed", {}, "boom")])
        self.assertIn("| fast | fast | 0 | evaluated | 20.12 | 12.0 | 21.00 |", table)
        self.assertIn("| fast-seed1 | fast | 1 | failed | - | - | - |", table)
        self.assertEqual(sweep.first_line(RuntimeError("a\nlast line\n")), "last line")


if __name__ == "__main__":
    unittest.main()
