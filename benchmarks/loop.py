"""The whole loop, longer than the demo: for each of two objects, the demo's generate -> train -> export ->
held-out evaluation -> closed-loop grasping with its own model, 10 grasp attempts each (20 in all).

Usage: python benchmarks/loop.py [--out out/bench-loop] [--objects noodle_cup_red noodle_cup_curry]
       [--attempts 10]

Prints per object and in all: held-out ADD-S AUC and pass at 2 cm for DOPE alone and with depth refinement,
grasps in the basket, failure causes and the minutes taken. Each object's report is in OUT/<object>/.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import time
from collections import Counter
from pathlib import Path

from nodes.demo_loop import DemoSettings, run_demo


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench-loop")
    parser.add_argument("--objects", nargs="+", default=["noodle_cup_red", "noodle_cup_curry"])
    parser.add_argument("--attempts", type=int, default=10, help="grasp attempts per object")
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs")
    successes, attempts, causes = 0, 0, Counter()
    for name in args.objects:
        out = Path(args.out) / name
        shutil.rmtree(out, ignore_errors=True)  # this benchmark's own output folder
        t0 = time.monotonic()
        run_demo(out, DemoSettings.small().model_copy(update={"objects": name, "attempts": args.attempts}))
        summary = json.loads((out / "summary.json").read_text())
        held_out, grasps = summary["held_out"], summary["grasps"]
        successes += grasps["successes"]
        attempts += grasps["attempts"]
        causes.update(grasps["failure_causes"])
        dope, refined = held_out["dope"], held_out["dope_depth"]
        print(f"{name}: held-out ADD-S AUC {dope['auc_0_10cm']:.3f} (DOPE), {refined['auc_0_10cm']:.3f} (+ depth); "
              f"pass at 2 cm {dope['pass_2cm']:.2f} / {refined['pass_2cm']:.2f}; "
              f"grasps {grasps['successes']} of {grasps['attempts']} "
              f"({grasps['failure_causes'] or 'no failures'}); {(time.monotonic() - t0) / 60:.1f} min")
    print(f"all: {successes} of {attempts} grasps; failures {dict(causes) or 'none'}")


if __name__ == "__main__":
    main()
