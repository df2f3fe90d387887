"""Worker processes end with the command that started them."""

from __future__ import annotations

import os
import threading
import time

PARENT_CHECK_SECONDS = 0.5  # how often a worker looks whether its parent is still there


def exit_with_parent(parent_pid: int) -> None:
    """Start a daemon thread that ends this process as soon as ``parent_pid`` is no longer its
    parent (the parent was killed, even by SIGKILL): no orphan keeps writing outputs."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
