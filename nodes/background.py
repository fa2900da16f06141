"""Long jobs (generation, training) run by a node on a thread, so its executor keeps serving callbacks."""

from __future__ import annotations

import threading
import traceback


class BackgroundJob:
    """Runs ``work()`` on a daemon thread; ``done``, ``result`` and ``error`` (message) afterwards."""

    def __init__(self, work):
        self.done, self.result, self.error = False, None, None
        self._thread = threading.Thread(target=self._run, args=(work,), daemon=True)
        self._thread.start()

    def _run(self, work) -> None:
        try:
            self.result = work()
        except Exception as exc:  # noqa: BLE001 - reported to the node, which publishes it
            self.error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()
        finally:
            self.done = True

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)
