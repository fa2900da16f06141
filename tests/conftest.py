import numpy as np
import pytest

from pegasus_gen.splats.cloud import SplatCloud


def random_cloud(rng: np.random.Generator, n: int, sh_degree: int = 3, labels=(0,), center=(0, 0, 0),
                 extent=0.5, scale_range=(0.01, 0.08), opacity_range=(0.2, 0.99)) -> SplatCloud:
    """n random anisotropic Gaussians with random SH in a cube of half-size ``extent`` around ``center``."""
    k = (sh_degree + 1) ** 2
    op = rng.uniform(*opacity_range, n)
    return SplatCloud(
        means=np.asarray(center) + rng.uniform(-extent, extent, size=(n, 3)),
        quats_wxyz=rng.normal(size=(n, 4)),
        log_scales=np.log(rng.uniform(*scale_range, size=(n, 3))),
        opacity_logits=np.log(op / (1 - op)),
        sh=np.concatenate([rng.normal(0, 0.8, size=(n, 1, 3)), rng.normal(0, 0.3, size=(n, k - 1, 3))], axis=1),
        labels=rng.choice(np.asarray(labels), n),
    )


def one_line_error(capsys):
    """The one error line of stderr (progress bars of generate, validate and view aside), and no traceback."""
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if not line.startswith(("generate:", "validate:", "view:"))]
    assert len(lines) == 1 and lines[0].startswith("pegasus: error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def library(tmp_path_factory):
    """The built-in demo library (8 objects, 3 environments), built once per test session; tests only read it."""
    from pegasus_gen.assets.demo import build_demo_library
    from pegasus_gen.assets.library import AssetLibrary

    lib = AssetLibrary(tmp_path_factory.mktemp("lib"))
    build_demo_library(lib)
    return lib


@pytest.fixture(scope="session")
def dope_dataset(library, tmp_path_factory):
    """A tiny BOP dataset for DOPE: 4 frames (320x240) of 3 red noodle cups seen from 0.28-0.32 m."""
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    out = tmp_path_factory.mktemp("ds") / "ds"
    return generate(load_config(None, [f"output={out}", f"library={library.root}", "scenes=1", "frames_per_scene=4",
                                       "camera.width=320", "camera.height=240", "device=cpu",
                                       "environments=[wooden_table]", "objects=[{asset: 1, count: [1, 1]}]",
                                       "trajectory.distance=[0.28, 0.32]"]))


@pytest.fixture(scope="session")
def overfit_dope(dope_dataset, tmp_path_factory):
    """The light DOPE model without BatchNorm trained 500 steps (160 px crops, no augmentation) on
    ``dope_dataset``: its run folder (last.pt, loss.csv, ...). (With BatchNorm the same 500 steps leave one
    of the 4 training instances 5.7 cm off.)"""
    from dope_training.train import TrainConfig, train

    return train(TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red",
                             out=str(tmp_path_factory.mktemp("overfit") / "run"), size=160, batch_size=4, epochs=500,
                             lr=1e-3, batch_norm=False, augment=False, loader_workers=0, device="cpu",
                             checkpoint_every=500))
