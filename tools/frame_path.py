"""The path of a frame through the service, counted: the Python calls, modules and packages
between Zenoh's callback and the ``tag`` put, and the objects wrapped around OpenCV's detector.

An in-process service (the default settings: OpenCV's detector under the frame deadline,
the second look, the veto) answers HD720 frames of one marker from a raw-frame camera; a
profile hook (``sys.setprofile``) counts, for each frame:

- in Zenoh's callback thread, every call from the service's subscriber callback on;
- in the worker thread, every call from the moment it takes the frame out of its stream's
  mailbox (``Scheduler.take`` returns it) to the first Zenoh ``put`` (the ``tag``'s).

Reported per frame (the median over ``--frames``): Python calls (all, and the package's
own), the distinct functions and modules of the package they run in, its subpackages
(``service``, ``wire``, ...; a top-level module counts as one), the C calls, and the
wrappers: the distinct classes whose methods are on the stack when OpenCV's
``detectMarkers`` runs. Counting needs no particular name in the service but the mailbox's
``take``; run it from the repository root: ``python -m tools.frame_path [--frames N]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

import zenoh_perception
from tools.rig import Camera, Listener, marker_frame
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint

PACKAGE = Path(zenoh_perception.__file__ or "").resolve().parent


@dataclass
class FramePath:
    """What one frame's path ran."""

    calls: int = 0
    own_calls: int = 0
    c_calls: int = 0
    functions: set[str] = field(default_factory=set)
    order: list[str] = field(default_factory=list)
    modules: set[str] = field(default_factory=set)
    wrappers: list[str] = field(default_factory=list)
    done: bool = False

    def summary(self) -> dict[str, Any]:
        packages = {m.split(".")[0] if "." in m else "(top)" for m in self.modules}
        return {
            "python_calls": self.calls,
            "package_calls": self.own_calls,
            "c_calls": self.c_calls,
            "package_functions": len(self.functions),
            "modules": len(self.modules),
            "subpackages": len(packages),
            "wrappers": len(self.wrappers),
            "wrapper_classes": self.wrappers,
        }


def _module_of(code: types.CodeType) -> str | None:
    """The package's module a code object is in (``service.stream``), or None."""
    try:
        path = Path(code.co_filename).resolve().relative_to(PACKAGE)
    except ValueError:
        return None
    return ".".join(path.with_suffix("").parts)


class Counter:
    """The profile hooks of both threads, counting into the current :class:`FramePath`."""

    def __init__(self) -> None:
        self.path = FramePath()
        self._lock = threading.Lock()
        self._worker_armed = False

    def _count(self, frame: types.FrameType, event: str, arg: Any) -> None:
        path = self.path
        if path.done:
            return
        if event == "call":
            path.calls += 1
            module = _module_of(frame.f_code)
            if module is not None:
                path.own_calls += 1
                path.modules.add(module)
                path.functions.add(f"{module}.{frame.f_code.co_qualname}")
                path.order.append(f"{module}.{frame.f_code.co_qualname}")
        elif event == "c_call":
            path.c_calls += 1
            name = getattr(arg, "__name__", "")
            if name in ("detectMarkers", "detectMarkersMultiDict") and not path.wrappers:
                path.wrappers = self._wrappers(frame)
            if name == "put" and type(getattr(arg, "__self__", None)).__name__ == "Publisher":
                path.done = True

    @staticmethod
    def _wrappers(frame: types.FrameType | None) -> list[str]:
        found: list[str] = []
        while frame is not None:
            owner = frame.f_locals.get("self")
            if owner is not None and _module_of(frame.f_code) is not None:
                name = type(owner).__name__
                if name not in found:
                    found.append(name)
            frame = frame.f_back
        return list(reversed(found))

    def callback_hook(self, frame: types.FrameType, event: str, arg: Any) -> None:
        with self._lock:
            self._count(frame, event, arg)

    def worker_hook(self, frame: types.FrameType, event: str, arg: Any) -> None:
        with self._lock:
            if self._worker_armed:
                self._count(frame, event, arg)
            elif event == "return" and frame.f_code.co_name == "take" and arg is not None:
                self._worker_armed = True

    def next_frame(self) -> FramePath:
        with self._lock:
            done, self.path = self.path, FramePath()
            self._worker_armed = False
        return done


class _ProfiledSession:
    """The service's session, whose subscribers' callbacks run under the callback hook."""

    def __init__(self, session: zenoh.Session, hook: Callable[..., None]) -> None:
        self._session = session
        self._hook = hook

    def declare_subscriber(self, key: Any, handler: Any, **kwargs: Any) -> Any:
        hook = self._hook

        def profiled(sample: zenoh.Sample) -> None:
            sys.setprofile(hook)
            try:
                handler(sample)
            finally:
                sys.setprofile(None)

        return self._session.declare_subscriber(key, profiled, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)


def main(frames: int) -> dict[str, Any]:
    endpoint = loopback_endpoint()
    settings = Settings.from_flat(stats_interval_s=0)
    counter = Counter()
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as session,
        zenoh.open(loopback_config(connect=[endpoint])) as camera_session,
    ):
        profiled = _ProfiledSession(session, counter.callback_hook)
        service = PerceptionService(profiled, settings)  # type: ignore[arg-type]
        threading.setprofile(counter.worker_hook)  # the workers the service starts
        try:
            service.start()
        finally:
            threading.setprofile(None)
        with service:
            camera = Camera(camera_session)
            listener = Listener(camera_session)
            camera.wait_matched()
            frame = marker_frame(1280, 720, 7, side=120)
            paths: list[FramePath] = []
            for seq in range(frames + 2):  # the first two open the stream and warm it
                counter.next_frame()
                camera.put(frame, seq)
                listener.record_for(seq, timeout=60.0)
                path = counter.next_frame()
                if seq >= 2 and path.done:
                    paths.append(path)
            listener.close()
            camera.close()
    summaries = [p.summary() for p in paths]
    numeric = [k for k, v in summaries[0].items() if isinstance(v, int)]
    result: dict[str, Any] = {k: statistics.median(s[k] for s in summaries) for k in numeric}
    result["wrapper_classes"] = summaries[0]["wrapper_classes"]
    result["frames"] = len(summaries)
    result["modules_seen"] = sorted(set().union(*(p.modules for p in paths)))
    result["calls_of_the_last_frame"] = paths[-1].order
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=16)
    args = parser.parse_args()
    print(json.dumps(main(args.frames), indent=2))
