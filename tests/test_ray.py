"""Generation as Ray tasks on a local Ray instance with 2 CPUs: the same dataset as one process, and what a
killed or failing task leaves."""

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_generate import config, dataset_files

from pegasus_gen.dataset.generate import generate
from pegasus_gen.errors import PegasusError

ray = pytest.importorskip("ray")  # in the test extra: a missing ray is an install error, reported as a skip


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def options(library, out, *extra):
    return config(library, out, "scenes=4", "frames_per_scene=2", "camera.width=160", "camera.height=120", *extra)


@pytest.fixture(scope="module")
def one_process(library, tmp_path_factory):
    return generate(options(library, tmp_path_factory.mktemp("one") / "ds"))


def same_files(a: Path, b: Path) -> None:
    got, want = dataset_files(a), dataset_files(b)
    assert sorted(got) == sorted(want)
    assert [k for k in want if got[k] != want[k]] == []


def test_a_ray_run_equals_a_one_process_run_file_by_file(library, tmp_path, local_ray, one_process):
    same_files(generate(options(library, tmp_path / "ray", "ray=auto")), one_process)


def scene_tasks() -> list[int]:
    """pids of the Ray workers running a scene task now (Ray titles them ``ray::_scene_task``)."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and (proc / "cmdline").read_bytes().startswith(b"ray::_scene_task"):
                pids.append(int(proc.name))
        except OSError:
            continue
    return pids


def test_a_task_killed_mid_scene_leaves_no_partial_scene_and_is_retried(library, tmp_path, local_ray, one_process):
    out = tmp_path / "killed"
    result = {}
    run = threading.Thread(target=lambda: result.update(out=generate(options(library, out, "ray=auto"))))
    run.start()
    killed, deadline = [], time.monotonic() + 300
    while not killed and run.is_alive() and time.monotonic() < deadline:
        split = out / "train_pbr"
        if split.is_dir() and any(p.name.startswith(".") for p in split.iterdir()):  # a scene is being built
            for pid in scene_tasks():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
        time.sleep(0.01)
    run.join(600)
    assert killed, "no scene task was caught mid-scene"
    assert result["out"] == out  # every scene made it: the killed ones were retried
    assert not [p for p in (out / "train_pbr").iterdir() if p.name.startswith(".")]
    same_files(out, one_process)


def test_a_scene_failing_every_try_is_reported_after_the_others_are_written(library, tmp_path, local_ray,
                                                                           one_process):
    out = tmp_path / "blocked"
    generate(options(library, out))
    split = out / "train_pbr"
    for scene in ("000002", "000003"):
        shutil.rmtree(split / scene)
    (split / "000002").write_text("a file where scene 2's folder must go: every try fails to rename into place")
    with pytest.raises(PegasusError, match=r"scenes 2 failed 3 times \(scene 2: NotADirectoryError.*--resume"):
        generate(options(library, out, "ray=auto"), resume=True)
    assert sorted(p.name for p in split.iterdir() if p.is_dir()) == ["000000", "000001", "000003"]
    (split / "000002").unlink()
    generate(options(library, out, "ray=auto"), resume=True)
    same_files(out, one_process)


def test_an_unreachable_cluster_is_one_line_and_touches_nothing(library, tmp_path):
    out = tmp_path / "ds"
    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "generate", f"library={library.root}",
                             "scenes=1", "--out", str(out), "--ray", "127.0.0.1:9"], capture_output=True, text=True)
    assert result.returncode == 2
    assert "--ray 127.0.0.1:9: cannot reach a Ray cluster" in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()
