"""Scenes as Ray tasks (``pegasus generate --ray``): one machine's cores or a cluster's.

``ray`` is ``auto`` (the running cluster: ``ray start --head`` on one node, ``ray start --address HEAD:6379``
on the others), ``local`` (a private Ray instance on this machine with ``workers`` CPUs, shut down at the
end) or a cluster address (``HEAD:6379`` or ``ray://HEAD:10001``). A Ray instance already initialised in
this process is used as it is.

Each task builds one scene exactly as a local run does (``build_scene``: a hidden temporary folder renamed
into place when complete) from the same seeds, so the dataset is byte-identical to a one-process run and
``--resume`` works the same. The assets are loaded once by the driver and shared through Ray's object store,
not re-read by every task. A task whose worker dies or raises is retried (``RETRIES`` times); scenes that
still fail are reported together at the end, after every other scene is written. On a cluster the output
folder must be on storage every node mounts at the same path (NFS, a shared volume), and the library too
only for the driver.
"""

from __future__ import annotations

import contextlib
import socket
from pathlib import Path
from typing import Callable

from tqdm import tqdm

from pegasus_gen.dataset.config import GenerateConfig
from pegasus_gen.errors import PegasusError

RETRIES = 2  # further tries of a failed scene


def _ray():
    try:
        import ray
    except ImportError:
        raise PegasusError("--ray needs the ray package: pip install 'pegasus-stack[ray]'") from None
    return ray


PROBE_TIMEOUT_S = 5.0


def _probe(address: str) -> None:
    """A TCP connection to a cluster ``address`` (HOST:PORT, or ray://HOST:PORT); one clear error when it
    fails, before Ray's own client retries for minutes."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise PegasusError(f"--ray {address}: expected auto, local, HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_TIMEOUT_S).close()
    except OSError as exc:
        raise PegasusError(f"--ray {address}: cannot reach a Ray cluster ({exc.strerror or exc})") from None


@contextlib.contextmanager
def ray_session(address: str | None, cpus: int):
    """Joined to (or, for ``local``, running) the Ray instance of ``address`` inside the block; nothing for
    None. An instance this call started is shut down at the end. Connects before anything is written, so an
    unreachable cluster leaves the output untouched."""
    if address is None:
        yield
        return
    ray = _ray()
    started = False
    if not ray.is_initialized():
        try:
            if address == "local":
                ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False)
                started = True
            else:
                if address != "auto":
                    _probe(address)
                ray.init(address=address, include_dashboard=False, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise PegasusError(f"--ray {address}: cannot reach a Ray cluster ({str(exc).splitlines()[0]})") from None
    try:
        yield
    finally:
        if started:
            ray.shutdown()


def _scene_task(build: Callable, split: str, scene_id: int, cfg: GenerateConfig, assets) -> int:
    try:
        build(Path(split), scene_id, cfg, assets)
    except Exception as exc:  # one line in Ray's retry notices, not the whole traceback
        raise RuntimeError(f"scene {scene_id}: {type(exc).__name__}: {exc}") from None
    return scene_id


def build_on_ray(build: Callable, split: Path, todo: list[int], cfg: GenerateConfig, assets, bar: tqdm) -> None:
    """Build each of the ``todo`` scenes of ``split`` with ``build(split, scene_id, cfg, assets)`` (generate's
    build_scene) as a Ray task, inside a ``ray_session``; ``bar`` advances by a scene's frames when its task
    completes. Raises PegasusError naming the scenes that failed every try."""
    ray = _ray()
    task = ray.remote(num_cpus=1, max_retries=RETRIES, retry_exceptions=True)(_scene_task)
    shared = ray.put(assets)
    pending = {task.remote(build, str(split), s, cfg, shared): s for s in todo}
    failed = {}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        scene_id = pending.pop(done[0])
        try:
            ray.get(done[0])
            bar.update(cfg.frames_per_scene)
        except Exception as exc:  # a task's own error, or its worker lost, after every retry
            failed[scene_id] = str(getattr(exc, "cause", None) or exc).strip().splitlines()[-1]
    if failed:
        first = min(failed)
        names = ", ".join(map(str, sorted(failed)))
        raise PegasusError(f"scenes {names} failed {RETRIES + 1} times ({failed[first]}); "
                           "the others are written: --resume retries the failed ones")
