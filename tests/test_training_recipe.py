"""The CPU training recipe learns: a short fixed-budget run of the demo's recipe (a fixed seed) reaches, on
frames of an environment left out of training seen with the simulated cell's camera, a detection rate and
a depth-refined pass rate that DOPE's own recipe (plain MSE, no BatchNorm, the image's shorter side fitted
into the crop, GT labels for the symmetric cup) does not reach in the same budget (docs/TRAINING.md).
Slow (about 5 minutes on a 2-core CPU): ``make test-all``."""

import pytest
import yaml

from dope_training.evaluate import evaluate
from dope_training.infer import DopeModel
from dope_training.train import TrainConfig, train
from nodes.demo_loop import DemoSettings, held_out_overrides
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate

FRAMES = 240
EPOCHS = 20  # about 3 minutes of training on the 2-core machine
# Measured with seed 0: this recipe 1.00 detected, 0.875 refined within 2 cm (ADD-S); DOPE's defaults on the
# same data and budget: 0.00 and 0.00 (no centroid belief above 0.1 on any held-out frame).
THRESHOLD_DETECTED, THRESHOLD_REFINED_2CM = 0.5, 0.5


@pytest.mark.slow
def test_a_short_run_of_the_cpu_recipe_finds_and_places_held_out_cups(library, tmp_path):
    s = DemoSettings.small()
    config = s.dataset_config(library.root) | {"scenes": FRAMES // s.frames, "output": str(tmp_path / "train")}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    data = generate(load_config(tmp_path / "config.yaml"))
    held_out = generate(load_config(None, [f"output={tmp_path / 'held_out'}",
                                           *held_out_overrides(library.root, "noodle_cup_red", frames=10)]))
    run = train(TrainConfig(data=[str(data)], object="noodle_cup_red", out=str(tmp_path / "run"), loader_workers=0,
                            device="cpu", seed=0, **(s.train_fields() | {"epochs": EPOCHS})))
    report = evaluate(DopeModel(run / "last.pt"), held_out, "train_pbr", refine=True)
    detected = report["detected"] / report["instances"]
    refined = report["refined"]["ADD-S"]
    assert report["instances"] >= 10
    assert detected >= THRESHOLD_DETECTED and refined["pass_2cm"] >= THRESHOLD_REFINED_2CM, report
