"""SIGINT / SIGTERM as a stop event, shared by every long-running command, and how such a
command's process ends.

A long-running command may return while threads of its process are still inside OpenCV or
Zenoh: the worker in the middle of a frame, a read the watchdog abandoned (service/guard.py),
both daemon threads that nobody can stop. If the interpreter then finalizes, such a thread that
comes back for the GIL is unwound by force (``pthread_exit``) through C++ code that catches
everything, and the process dies of SIGABRT (``FATAL: exception not rethrown``) or SIGSEGV
instead of exiting with its code. :func:`leave` ends the process without finalizing the
interpreter, once everything a normal exit would write or clean up is done.
"""

from __future__ import annotations

import atexit
import logging
import os
import signal
import sys
import threading
import time
from contextlib import suppress
from typing import Final, NoReturn

log = logging.getLogger("zenoh_perception.service.signals")

#: Seconds that threads the interpreter would wait for at exit (not daemon threads) get to end.
JOIN_S: Final = 0.5


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM; the command then shuts down cleanly with exit 0."""
    stop = threading.Event()

    def handle(signum: int, _frame: object) -> None:
        log.info("event=signal signal=%s", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handle)
    signal.signal(signal.SIGTERM, handle)
    return stop


def leave(code: int, *, join_s: float = JOIN_S) -> NoReturn:
    """End the process with exit status ``code``, without finalizing the interpreter under
    threads still inside OpenCV or Zenoh (see the module documentation).

    The caller has closed what it opened (the service, its child processes and shared
    memory, the Zenoh session). Then, as a normal exit would: threads that are not daemon
    threads get ``join_s`` seconds in all to end, the ``atexit`` handlers run (logging's flush
    and close, multiprocessing's end of its children), stdout and stderr are flushed. Then
    ``os._exit(code)``: no finalization, no C++ static destructors, whatever the other threads
    are doing.
    """
    deadline = time.monotonic() + join_s
    current = threading.current_thread()
    for thread in threading.enumerate():
        if thread is not current and not thread.daemon:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
    atexit._run_exitfuncs()  # what the interpreter runs at exit, run here
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            with suppress(OSError, ValueError):  # closed, or its reader gone: nothing to flush
                stream.flush()
    os._exit(code)
