"""The CameraInfos the service receives: each decoded and checked, handed to the streams it
is for, and kept (a bounded number, the newest) for the streams made later.

With several streams (a wildcard or list input) a CameraInfo is its stream's (its key named
under ``camera_info_key`` as the frames' keys are under the input: a pattern or list there
too); a concrete ``camera_info_key``'s is every stream's (kept under the name ``""``).
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Mapping

import zenoh

from zenoh_perception.errors import CameraInfoError, IntrinsicsError
from zenoh_perception.service.inputs import StreamNaming
from zenoh_perception.service.logs import LimitedLog
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.service.stream import CameraInfo, Stream
from zenoh_perception.settings.sections import Inputs
from zenoh_perception.wire.camera_info import check_camera_info_size, decode_camera_info

log = logging.getLogger(__name__)


class CameraInfos:
    """The CameraInfo subscription's callback (:meth:`on_sample`) and the infos kept.

    ``streams`` is the service's streams by name and ``lock`` the lock that guards them: an
    info is kept and handed to the streams there in one step under it, so a stream made
    meanwhile (which asks :meth:`for_stream` under the same lock) gets it either way.
    """

    def __init__(
        self,
        inputs: Inputs,
        totals: ServiceStats,
        gate: LogGate,
        *,
        naming: StreamNaming,
        streams: Mapping[str, Stream],
        lock: threading.Lock,
    ) -> None:
        self._max_streams = inputs.max_streams
        self._totals = totals
        self._log = LimitedLog(log, gate)
        self._naming = naming
        self._streams = streams
        self._lock = lock
        # CameraInfos by stream name ("" for every stream), for streams made later too
        self._infos: OrderedDict[str, CameraInfo] = OrderedDict()

    def for_stream(self, name: str) -> CameraInfo | None:
        """The CameraInfo of a stream ``name`` made now, if any; call it holding ``lock``."""
        return self._infos.get(name) or self._infos.get("")

    def on_sample(self, sample: zenoh.Sample) -> None:
        """A CameraInfo arrived: counted, and used by its streams when it decodes."""
        try:
            check_camera_info_size(len(sample.payload))  # before the copy out of Zenoh
            info = decode_camera_info(sample.payload.to_bytes())
        except (CameraInfoError, IntrinsicsError) as err:
            # Counted apart from frames: a bad CameraInfo is no frame, and the intrinsics in
            # use stay as they were.
            self._totals.on_camera_info(err.reason)
            self._log(
                logging.WARNING,
                f"camera_info:{err.reason}",
                "camera_info_rejected",
                reason=err.reason,
                detail=err,
            )
            return
        self._totals.on_camera_info(None)
        intrinsics = info.intrinsics
        camera: CameraInfo = (intrinsics, (info.width, info.height))
        name = self._naming.of_camera_info(str(sample.key_expr))
        with self._lock:
            self._infos[name] = camera
            self._infos.move_to_end(name)
            while len(self._infos) > self._max_streams:
                self._infos.popitem(last=False)
            targets = [s for s in self._streams.values() if name in ("", s.name)]
        changed = [stream.use_camera_info(camera) for stream in targets]
        if any(changed):
            # A camera whose intrinsics change on every message would flood the log: the
            # line is rate-limited and the status always shows the intrinsics in use.
            self._log(
                logging.INFO,
                "intrinsics",
                "intrinsics",
                **self._naming.fields(name),
                fx=f"{intrinsics.fx:.2f}",
                fy=f"{intrinsics.fy:.2f}",
                cx=f"{intrinsics.cx:.2f}",
                cy=f"{intrinsics.cy:.2f}",
                width=info.width,
                height=info.height,
            )
