"""The wheel, installed into a fresh virtualenv, works away from the source tree: the command runs and finds
the launch files it installed."""

from __future__ import annotations

import os
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILES = sorted(p.name for p in (ROOT / "launch").glob("*.launch.py"))


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(bin folder, working folder) of a fresh venv with only the built wheel installed; its dependencies come
    from this environment's site-packages through a .pth file (the wheel itself is what is tested)."""
    tmp = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                    str(tmp / "dist"), str(ROOT)], check=True, cwd=tmp)
    wheel = next((tmp / "dist").glob("pegasus_stack-*.whl"))
    env_dir = tmp / "venv"
    venv.create(env_dir, with_pip=True)
    bin_dir = env_dir / "bin"
    purelib = subprocess.run([str(bin_dir / "python"), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([str(bin_dir / "python"), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
                   check=True)
    work = tmp / "elsewhere"
    work.mkdir()
    return bin_dir, work


def run(installed, *args):
    bin_dir, work = installed
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(bin_dir / args[0]), *args[1:]], cwd=work, env=env, capture_output=True, text=True)


def test_the_package_comes_from_the_wheel_not_the_source(installed):
    out = run(installed, "python", "-c", "import pegasus_gen, nodes.launch; print(pegasus_gen.__file__); "
                                         "print(nodes.launch.launch_dir())")
    assert out.returncode == 0, out.stderr
    module_file, launch_dir = out.stdout.split()
    assert str(installed[0].parent) in module_file and str(ROOT) not in module_file
    assert str(installed[0].parent) in launch_dir


def test_launch_help_lists_the_installed_launch_files(installed):
    out = run(installed, "pegasus", "launch", "--help")
    assert out.returncode == 0, out.stderr
    assert len(LAUNCH_FILES) == 3 and all(name in out.stdout for name in LAUNCH_FILES)


def test_an_installed_launch_file_is_found_by_name(installed):
    out = run(installed, "pegasus", "launch", "sim_pick_place.launch.py", "no_such_argument:=1")
    assert out.returncode == 2
    assert "unknown launch argument(s) no_such_argument" in out.stderr and "attempts" in out.stderr
