"""Scenes of a run in parallel, each built by the one per-scene entry ``dataset.scene.build_scene``: in worker
processes on this machine (``build_in_processes``) or as Ray tasks (``build_on_ray``) on one machine's cores or
a cluster's.

Worker processes: ``workers`` of them (spawned, as forked numba/OpenMP thread pools are not safe), each dying
with the run (even a kill -9 of it), sharing the CPU cores and loading the assets once.

Ray: ``ray`` is ``auto`` (the running cluster: ``ray start --head`` on one node, ``ray start --address HEAD:6379``
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
import ctypes
import multiprocessing
import os
import signal
import socket
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from tqdm import tqdm

from pegasus_gen.dataset.config import GenerateConfig
from pegasus_gen.dataset.scene import Assets, build_scene, load_assets
from pegasus_gen.errors import PegasusError

_worker_assets: Assets | None = None


def die_with_parent(parent_pid: int) -> None:
    """In a child process: be killed (SIGKILL) when the parent dies, even by kill -9 (Linux
    ``PR_SET_PDEATHSIG``; elsewhere nothing); exit at once if it is already gone."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:
        os._exit(1)


def _init_worker(cfg: GenerateConfig, parent_pid: int) -> None:
    """Worker process start: die with the parent, share the CPU cores between the workers and load the
    assets once."""
    global _worker_assets
    import numba

    die_with_parent(parent_pid)
    numba.set_num_threads(max(1, (os.cpu_count() or 1) // cfg.workers))
    _worker_assets = load_assets(cfg)


def _worker_scene(split: Path, scene_id: int, cfg: GenerateConfig, frames_done) -> None:
    build_scene(split, scene_id, cfg, _worker_assets, lambda: frames_done.put(1))


def build_in_processes(split: Path, todo: list[int], cfg: GenerateConfig, bar: tqdm) -> None:
    """``todo`` scenes spread over ``cfg.workers`` processes; ``bar`` advances per written frame."""
    from multiprocessing.managers import SyncManager

    context = multiprocessing.get_context("spawn")  # forked numba/OpenMP thread pools are not safe
    manager = SyncManager(ctx=context)
    manager.start(die_with_parent, (os.getpid(),))
    with manager:
        frames_done = manager.Queue()
        with ProcessPoolExecutor(cfg.workers, mp_context=context, initializer=_init_worker,
                                 initargs=(cfg, os.getpid())) as pool:
            running = {pool.submit(_worker_scene, split, s, cfg, frames_done) for s in todo}
            try:
                while running:
                    done, running = wait(running, timeout=0.25, return_when=FIRST_COMPLETED)
                    while not frames_done.empty():
                        bar.update(frames_done.get())
                    for future in done:
                        future.result()  # a worker's error ends the run
            except BaseException:
                pool.shutdown(wait=True, cancel_futures=True)
                raise


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


def _scene_task(split: str, scene_id: int, cfg: GenerateConfig, assets: Assets) -> int:
    try:
        build_scene(Path(split), scene_id, cfg, assets)
    except Exception as exc:  # one line in Ray's retry notices, not the whole traceback
        raise RuntimeError(f"scene {scene_id}: {type(exc).__name__}: {exc}") from None
    return scene_id


def build_on_ray(split: Path, todo: list[int], cfg: GenerateConfig, assets: Assets, bar: tqdm) -> None:
    """Build each of the ``todo`` scenes of ``split`` with ``build_scene`` as a Ray task, inside a
    ``ray_session``; ``bar`` advances by a scene's frames when its task completes. Raises PegasusError naming
    the scenes that failed every try."""
    ray = _ray()
    task = ray.remote(num_cpus=1, max_retries=RETRIES, retry_exceptions=True)(_scene_task)
    shared = ray.put(assets)
    pending = {task.remote(str(split), s, cfg, shared): s for s in todo}
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
