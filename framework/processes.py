"""Helper processes that never outlive the run that started them.

A device may start a program of its own (the simulated vehicle, simulated
drives in another process). If the run is killed (``kill -9`` included),
nobody stops that program. :func:`exit_with_parent` makes a program exit by
itself as soon as the process that started it is gone; :func:`child_env`
tells it which process that is.
"""

from __future__ import annotations

import os
import threading
import time

#: the environment variable naming the process whose death ends a helper process
PARENT_ENV = "SURGIPLAN_PARENT_PID"
POLL_S = 0.2


def child_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a helper process: this process is its parent."""
    out = dict(os.environ if env is None else env)
    out[PARENT_ENV] = str(os.getpid())
    return out


def exit_with_parent(on_exit=None) -> bool:
    """If started with :func:`child_env`, exit (after ``on_exit()``, if given) as soon as the parent is gone.

    Returns whether a watch was started. The parent is gone when this process is re-parented (the usual case
    on POSIX) or the parent's pid no longer exists.
    """
    text = os.environ.get(PARENT_ENV)
    if not text or not text.isdigit():
        return False
    parent = int(text)
    if os.getppid() != parent:  # started through a shell or a launcher: watch the pid itself
        started_under = os.getppid()
    else:
        started_under = parent

    def gone() -> bool:
        if os.getppid() != started_under:
            return True
        try:
            os.kill(parent, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return False

    def watch() -> None:
        while not gone():
            time.sleep(POLL_S)
        if on_exit is not None:
            try:
                on_exit()
            except Exception:
                pass
        os._exit(3)

    threading.Thread(target=watch, name="surgiplan-exit-with-parent", daemon=True).start()
    return True
