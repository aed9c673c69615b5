"""The web demo's work folder goes away with the demo.

:func:`remove_on_exit` deletes the folder when the app is closed (``app.close()``, which gradio
also calls on Ctrl-C), when the Python process exits normally (``atexit``), and on SIGTERM
(turned into a normal exit where no other handler is installed), so that request folders with
uploaded photos do not pile up in ``/tmp``.
"""

from __future__ import annotations

import atexit
import shutil
import signal
import threading
from pathlib import Path

__all__ = ["remove_on_exit"]


def _sigterm_exit(signum, frame):
    raise SystemExit(128 + signum)


def remove_on_exit(app, folder: str | Path) -> None:
    """Delete ``folder`` when ``app`` closes or the process ends (see the module docstring)."""
    folder = Path(folder)

    def remove() -> None:
        shutil.rmtree(folder, ignore_errors=True)

    atexit.register(remove)
    close = getattr(app, "close", None)
    if callable(close):

        def close_and_remove(*args, **kwargs):
            try:
                return close(*args, **kwargs)
            finally:
                remove()

        app.close = close_and_remove
    if (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    ):
        signal.signal(signal.SIGTERM, _sigterm_exit)
