"""What the service tells about itself: the status document its queryable answers, and its
log lines at start and every ``stats_interval_s`` (one per stream with a wildcard input)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from typing import Any

from zenoh_perception import __version__
from zenoh_perception.service.logs import kv
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.service.stream import Stream
from zenoh_perception.settings import Settings
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.ros_topics import input_role

log = logging.getLogger(__name__)


def log_started(
    settings: Settings,
    ros: RosTransport,
    *,
    zid: object,
    named: bool,
    workers: int,
    endpoints: Mapping[str, str],
) -> None:
    """The ``event=started`` line: the version, the Zenoh id, mode and endpoints, the keys
    served and the settings that matter.

    ``named``: a wildcard or list input (streams named after their keys, up to
    ``max_streams``).
    """
    s = settings
    log.info(
        "event=started %s",
        kv(
            version=__version__,
            zid=zid,
            **endpoints,
            ros_transport=s.ros.ros_transport,
            input=",".join(ros.keys(input_role(InputKind.CDR))),
            compressed_input=",".join(ros.keys(input_role(InputKind.COMPRESSED))),
            tag=s.outputs.tag_key if named else ros.key("tag"),
            record=s.outputs.record_key,
            detector=s.detection.detector,
            dictionary=s.detection.dictionary,
            policy=s.selection.policy,
            metric=s.selection.metric,
            max_frame_bytes=s.limits.max_frame_bytes,
            max_frame_pixels=s.limits.max_frame_pixels,
            workers=workers,
            max_streams=s.inputs.max_streams if named else 1,
        ),
    )


def status_document(
    totals: dict[str, Any],
    streams: Sequence[Stream],
    *,
    retired_vetoes: Counter[str],
    named: bool,
    zid: str,
    worker_alive: bool,
    other_services: int,
    group: dict[str, Any] | None,
    held: list[str],
    settings: Settings,
) -> dict[str, Any]:
    """The JSON-ready status: the totals (a snapshot's ``as_dict``, completed here), each
    stream's status (``streams`` sorted by key), the vetoes of every stream served or
    forgotten (``retired_vetoes``: those forgotten), the service's own state (the other
    services' liveliness tokens seen, its share group's status, the keys it holds) and the
    effective settings.

    Without ``named`` (a concrete input) the totals' CameraInfo intrinsics are the one
    stream's.
    """
    per_stream = [stream.status() for stream in streams]
    vetoed = Counter(retired_vetoes)
    for stream in per_stream:
        vetoed.update(stream["vetoed_by_reason"])
    single = streams[0] if not named and streams else None
    intrinsics = None if single is None else single.intrinsics
    totals["camera_info"]["intrinsics"] = None if intrinsics is None else asdict(intrinsics)
    return {
        "service": "zenoh-perception",
        "version": __version__,
        "zid": zid,
        "worker_alive": worker_alive,
        **totals,
        "liveliness": {"other_services": other_services},
        "group": group,
        "vetoed_by_reason": dict(vetoed),
        "debug_image": {
            "watched": any(s.debug_watched.is_set() for s in streams),
            "published": sum(s.debug_images for s in streams),
        },
        "streams": per_stream,
        "held": held,
        "settings": settings.as_dict(),
    }


def log_stats(status: dict[str, Any], *, per_stream: bool, input_key: str) -> None:
    """The periodic stats line from a :func:`status_document` (and with ``per_stream`` one
    line per stream); while no frame has come, a line that says which key is awaited."""
    frames = status["frames"]
    if frames["received"] == 0:
        # a line of zeros says nothing: say what is awaited, and where
        log.info(
            "event=waiting_for_frames %s",
            kv(key=input_key, detail="no frame received yet"),
        )
        return
    latency = status["latency_ms"]
    budget = status["budget"]
    log.info(
        "event=stats received=%d processed=%d dropped=%d rejected=%d fps=%.1f "
        "latency_p50_ms=%.2f latency_p99_ms=%.2f over_budget=%d detect_ms_max=%.2f "
        "abandoned=%d abandoned_ms_max=%.2f publish_errors=%d processing_errors=%d",
        frames["received"],
        frames["processed"],
        frames["dropped"],
        frames["rejected"],
        status["fps"],
        latency["p50"],
        latency["p99"],
        budget["over_budget"],
        budget["detect_ms_max"],
        budget["abandoned"],
        budget["abandoned_ms_max"],
        sum(status["publish_errors"].values()),
        sum(status["processing_errors"].values()),
    )
    if not per_stream:
        return
    for stream in status["streams"]:
        frames, latency = stream["frames"], stream["latency_ms"]
        log.info(
            "event=stream_stats %s",
            kv(
                name=stream["name"],
                stream=stream["stream"],
                received=frames["received"],
                processed=frames["processed"],
                dropped=frames["dropped"],
                rejected=frames["rejected"],
                fps=f"{stream['fps']:.1f}",
                latency_p50_ms=f"{latency['p50']:.2f}",
                latency_p99_ms=f"{latency['p99']:.2f}",
                abandoned=stream["budget"]["abandoned"],
            ),
        )
