"""OpenCV's worker threads, set to sleep as soon as their share of a parallel call is done.

OpenCV's own thread pool (pthreads) keeps its workers, and the thread that called it, spinning
for a while after each parallel call (``OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER`` and ``_MAIN``
pause loops) so that a next call, if it comes at once, finds them awake. The service's
calls come in bursts a frame apart, with its own Python work between them (the veto, the
refinement, the record, Zenoh's threads): there the spinning holds the cores that work needs.
With both waits at 0 the service spent 1.8-3.3 ms less CPU a frame on HD720 frames and
answered sooner (docs/benchmarks.md, "OpenCV's spinning workers").

OpenCV reads these variables once, when the library is loaded: :func:`quiet_opencv_pool`
must run before the process first imports ``cv2``. A value the environment already holds
wins (a user who wants OpenCV's spinning sets ``OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER``).
Child processes (the frame deadline's detector) inherit the environment.
"""

from __future__ import annotations

import os
from typing import Final

#: The pool's active waits, in pause loops: 0, the workers sleep at once.
QUIET_POOL: Final = {
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "0",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "0",
}


def quiet_opencv_pool() -> None:
    """Set :data:`QUIET_POOL` in the environment where it is not set already (before ``cv2``
    is imported; see the module documentation)."""
    for name, value in QUIET_POOL.items():
        os.environ.setdefault(name, value)
