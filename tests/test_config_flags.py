"""Command-line flags made from pydantic configs: types, defaults, choices, tuples, booleans; one clear line
for a bad value; the configs' variant defaults and consistency checks."""

import argparse

import pytest

from dope_training.train_config import TrainConfig
from pegasus_gen.cli.main import main
from pegasus_gen.cli.options import add_config_flags, config_from_args
from pegasus_gen.errors import PegasusError
from pegasus_gen.scan.options import ScanOptions

FIELDS = ("data", "object", "variant", "epochs", "lr", "augment", "amp", "object_size", "vgg19")


def parse(argv):
    parser = argparse.ArgumentParser()
    add_config_flags(parser, TrainConfig, FIELDS, data={"action": "append", "nargs": None})
    return parser.parse_args(argv)


def test_flags_follow_the_fields_and_build_the_config():
    args = parse(["--data", "a", "--data", "b", "--object", "cup", "--epochs", "3", "--no-augment",
                  "--object-size", "0.1", "0.2", "0.3"])
    cfg = config_from_args(TrainConfig, args)
    assert cfg.data == ["a", "b"] and cfg.object == "cup" and cfg.epochs == 3
    assert cfg.augment is False and cfg.amp is True and cfg.object_size == (0.1, 0.2, 0.3) and cfg.vgg19 is None
    assert (cfg.variant, cfg.size, cfg.lr) == ("light", 320, 1e-3)  # the variant's defaults, filled in
    with pytest.raises(SystemExit):
        parse(["--data", "a", "--object", "cup", "--variant", "huge"])  # Literal -> argparse choices


def test_bad_values_are_one_line_naming_the_flag():
    with pytest.raises(PegasusError, match=r"^--epochs: .*greater than 0 \(got -1\)$"):
        config_from_args(TrainConfig, parse(["--data", "a", "--object", "cup", "--epochs", "-1"]))
    with pytest.raises(PegasusError, match="^an object scan needs --obj-id"):
        config_from_args(ScanOptions, argparse.Namespace(kind="object", name="x", aruco_size=0.05))


def test_variant_defaults_and_explicit_values():
    full = TrainConfig(data=["a"], object="cup", variant="full")
    assert (full.size, full.lr) == (400, 1e-4)
    assert TrainConfig(data=["a"], object="cup", size=128, lr=0.5).model_dump()["size"] == 128
    assert TrainConfig(**full.model_dump()) == full


def test_train_command_refuses_a_bad_value(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path), "--object", "1", "--epochs", "-1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--epochs" in err
