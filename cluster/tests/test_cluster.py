"""The cluster drivers' own logic, without Ray or the xtask binary: argument splitting, durations,
the metrics tail, exit-status classification, shard writing and the refusals that must come
before anything is written. Each test takes well under a second."""

from __future__ import annotations

import io
import json
import os
import pickle
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
import unittest
from contextlib import redirect_stderr
from pathlib import Path

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
