"""gsplat CUDA backend against the numba CPU backend (runs only where torch sees a GPU and gsplat works)."""

import numpy as np
import pytest

from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.renderer import cuda_status, render
from pegasus_gen.splats import procedural as synthetic

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not cuda_status()[0], reason=f"no CUDA: {cuda_status()[1]}")]


@pytest.mark.parametrize("eye,w,h,antialiased", [([0.7, -0.5, 0.55], 320, 240, False),
                                                 ([-0.3, 0.6, 0.9], 320, 240, False),
                                                 ([0.05, 0.02, 1.2], 320, 240, False),
                                                 ([0.7, -0.5, 0.55], 640, 480, False),
                                                 ([0.7, -0.5, 0.55], 320, 240, True)])
def test_cuda_and_cpu_backends_agree(eye, w, h, antialiased):
    rng = np.random.default_rng(0)
    env, objects, poses = synthetic.tabletop_scene(150_000, rng, sh_degree=3)
    scene = [env] + [o.transformed(T) for o, T in zip(objects, poses)]
    K = intrinsics_from_fov(w, h, 55)
    T = look_at(eye, [0, 0, 0.05])
    labels = tuple(range(7))
    cpu, gpu = (render(scene, K, T, w, h, background=(0.3, 0.3, 0.3), labels=labels, device=device,
                       antialiased=antialiased) for device in ("cpu", "cuda"))
    assert gpu.backend == "cuda"
    assert np.abs(cpu.rgb - gpu.rgb).mean() < 1 / 255
    both = (cpu.depth > 0) & (gpu.depth > 0)
    assert both.mean() > 0.5
    # depth by the CPU's rule (blended depth planes): 0.02 mm (median) from the CPU's on the CPU rasteriser
    assert np.median(np.abs(cpu.depth[both] - gpu.depth[both])) < 5e-4
    covered = cpu.alpha > 0.5
    assert (cpu.label[covered] == gpu.label[covered]).mean() > 0.99
    assert np.abs(cpu.label_weights - gpu.label_weights).mean() < 1e-3


def test_auto_picks_cuda_when_it_works():
    out = render(synthetic.tabletop_scene(1000, np.random.default_rng(1))[0], intrinsics_from_fov(64, 48, 60),
                 look_at([1, 0, 1], [0, 0, 0]), 64, 48, device="auto")
    assert out.backend == "cuda"


def test_contact_shadows_darken_alike_on_both_backends():
    import trimesh

    from pegasus_gen.dataset.config import ShadowConfig
    from pegasus_gen.render.shadows import contact_shadows

    env, objects, poses = synthetic.tabletop_scene(100_000, np.random.default_rng(2), sh_degree=3)
    placed = [o.transformed(T) for o, T in zip(objects, poses)]
    meshes = [trimesh.creation.box(bounds=[o.means.min(0), o.means.max(0)]).apply_transform(T)
              for o, T in zip(objects, poses)]
    shaded_env, shaded = contact_shadows(env, placed, meshes, ShadowConfig().params(), np.random.default_rng(0))
    w, h = 320, 240
    K, T = intrinsics_from_fov(w, h, 55), look_at([0.6, -0.4, 0.6], [0, 0, 0.05])
    shadow = {}
    for device in ("cpu", "cuda"):
        plain = render([env, *placed], K, T, w, h, device=device)
        dark = render([shaded_env, *shaded], K, T, w, h, device=device)
        shadow[device] = (plain.rgb - dark.rgb).mean(-1)
    assert (shadow["cpu"] > 0.02).mean() > 0.002
    assert np.abs(shadow["cpu"] - shadow["cuda"]).mean() < 1 / 255


def test_frames_replayed_from_cuda_graphs_equal_frames_run_directly(monkeypatch):
    """A scene's frames after its first replay the per-frame work from CUDA graphs (captured on the second use
    of the same intrinsics and outputs): each frame, kept while later ones render, equals the same frame rendered
    without graphs, also when the intrinsics or the requested labels change mid-scene."""
    from pegasus_gen.render import cuda as rasterizer_cuda

    env, objects, poses = synthetic.tabletop_scene(50_000, np.random.default_rng(3), sh_degree=3)
    scene = [env] + [o.transformed(T) for o, T in zip(objects, poses)]
    w, h = 320, 240
    wide, narrow = intrinsics_from_fov(w, h, 60), intrinsics_from_fov(w, h, 45)
    frames = [(wide, [0.7, -0.5, 0.55], (1, 2)), (wide, [-0.3, 0.6, 0.9], (1, 2)), (wide, [0.5, 0.5, 0.6], (1, 2)),
              (narrow, [0.6, 0.2, 0.7], (1, 2)), (wide, [0.1, -0.7, 0.5], (3,)), (wide, [-0.6, -0.3, 0.6], (1, 2))]
    outputs = {}
    for graphs in (False, True):
        monkeypatch.setattr(rasterizer_cuda, "GRAPHS", graphs)
        rasterizer_cuda._SCENE.clear()
        outputs[graphs] = [render(scene, K, look_at(eye, [0, 0, 0.05]), w, h, labels=labels, device="cuda")
                           for K, eye, labels in frames]
    assert any(isinstance(v, tuple) for v in rasterizer_cuda._SCENE["graphs"].values())  # graphs were replayed
    for direct, replayed in zip(outputs[False], outputs[True]):
        for name in ("rgb", "depth", "alpha", "label_weights"):
            np.testing.assert_allclose(getattr(replayed, name), getattr(direct, name), atol=1e-6, err_msg=name)
        np.testing.assert_array_equal(replayed.label, direct.label)
    assert np.abs(outputs[True][0].rgb - outputs[True][2].rgb).mean() > 0.01  # the frames differ
