#!/usr/bin/env python3
"""Runs one nerfstudio command (ns-train, ns-render, ns-export, ns-eval) where only package
registries are reachable, and times ns-train's training loop.

    .venv-interop/bin/python tests/interop/ns_offline.py [--timing FILE] ns-train ARGS...

Two things differ from calling the command directly:

* LPIPS. nerfacto builds torchmetrics' LPIPS metric when the model is set up (training, eval
  and render alike), and that metric loads torchvision's ImageNet AlexNet weights from
  download.pytorch.org, which cannot be reached here. When the weights are not already in the
  torch hub cache, the AlexNet backbone is built with random weights instead (torchmetrics'
  own linear LPIPS layers still load from its package): the command runs, every other metric
  is unchanged, and every LPIPS number it prints or writes is meaningless. A line on stderr
  says so. With the weights cached (`$TORCH_HOME/hub/checkpoints/`), nothing is patched.
* `--timing FILE` (ns-train only) writes {"train_loop_s", "iteration_s", "iterations",
  "process_s", "lpips_valid"} as JSON: the wall-clock seconds of nerfstudio's training loop
  (`Trainer.train`: iterations, callbacks, the final checkpoint), the sum over
  `Trainer.train_iteration` calls (forward, backward, optimiser step) and their count.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

ENTRYPOINTS = {
    "ns-train": "nerfstudio.scripts.train",
    "ns-render": "nerfstudio.scripts.render",
    "ns-export": "nerfstudio.scripts.exporter",
    "ns-eval": "nerfstudio.scripts.eval",
}


def lpips_backbone_offline() -> bool:
    """Builds LPIPS' AlexNet with random weights when the ImageNet ones are not cached.
    Returns whether LPIPS values will be meaningful."""
    import torch.hub
    import torchvision

    url = torchvision.models.AlexNet_Weights.DEFAULT.url
    cached = Path(torch.hub.get_dir()) / "checkpoints" / os.path.basename(url)
    if cached.is_file():
        return True
    import torchmetrics.functional.image.lpips as tm_lpips

    original = tm_lpips._get_tv_model_features

    def features(net: str, pretrained: bool = False):
        return original(net, pretrained=False)

    tm_lpips._get_tv_model_features = features
    print(f"ns_offline: {cached} not cached ({url} unreachable): LPIPS uses a random AlexNet "
          "backbone, its values are meaningless", file=sys.stderr)
    return False


def main() -> int:
    args = sys.argv[1:]
    timing = None
    if len(args) >= 2 and args[0] == "--timing":
        timing, args = Path(args[1]), args[2:]
    if not args or args[0] not in ENTRYPOINTS:
        print(f"usage: ns_offline.py [--timing FILE] {{{','.join(ENTRYPOINTS)}}} ARGS...", file=sys.stderr)
        return 2
    if timing is not None and args[0] != "ns-train":
        print("ns_offline.py: --timing applies to ns-train only", file=sys.stderr)
        return 2
    t_process = time.perf_counter()
    lpips_valid = lpips_backbone_offline()
    stats = {"train_loop_s": None, "iteration_s": 0.0, "iterations": 0}
    if timing is not None:
        from nerfstudio.engine.trainer import Trainer

        train, train_iteration = Trainer.train, Trainer.train_iteration

        def timed_train(self):
            t0 = time.perf_counter()
            try:
                return train(self)
            finally:
                stats["train_loop_s"] = time.perf_counter() - t0

        def timed_iteration(self, step):
            t0 = time.perf_counter()
            out = train_iteration(self, step)
            stats["iteration_s"] += time.perf_counter() - t0
            stats["iterations"] += 1
            return out

        Trainer.train, Trainer.train_iteration = timed_train, timed_iteration

    import importlib

    sys.argv = args
    entry = importlib.import_module(ENTRYPOINTS[args[0]]).entrypoint
    try:
        entry()
    finally:
        if timing is not None:
            stats["process_s"] = time.perf_counter() - t_process
            stats["lpips_valid"] = lpips_valid
            tmp = timing.with_name(timing.name + ".tmp")
            tmp.write_text(json.dumps(stats, indent=2) + "\n")
            tmp.replace(timing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
