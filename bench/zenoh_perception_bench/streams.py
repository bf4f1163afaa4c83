"""``bench --streams``: several cameras on one service, and whether a large one holds up the
small ones.

One ``zenoh-perception run`` process (OpenCV's detector, default settings: a worker per core)
on a wildcard input, a stream per camera. The bench's cameras each put generated frames
(1-4 tags) from a thread of their own at a fixed rate, newest frame winning in the service:

1. three VGA cameras at 15 Hz, alone;
2. the same three, while an HD2K camera streams beside them at 15 Hz.

Per camera and phase: frames put, frames answered (a record of that frame's ``seq`` came back
on the camera's own record key), the median and 95th percentile from put to record, and the
service's own detection time from the records; beside them OpenCV's default on the same frames
in the bench's process (read back to back, nothing else running). Goals (:data:`GOAL_ANSWERED`,
:data:`GOAL_LATENCY_MS`): each VGA camera keeps at least 95 % of its frames answered beside the
HD2K one, and its median latency within 10 ms of what it was alone.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.service.status import query_status
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.records import decode_record
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.overhead import frames_at
from zenoh_perception_bench.processes import STARTUP_TIMEOUT_S, ServiceProcess
from zenoh_perception_bench.runners import DICTIONARY, Baseline

Image = npt.NDArray[np.uint8]

PREFIX: Final = "bench/streams"
#: The cameras: name -> resolution. The first three are the small ones held to the goals.
SMALL: Final = ("vga1", "vga2", "vga3")
LARGE: Final = "hd2k"
RESOLUTION: Final = {**dict.fromkeys(SMALL, "VGA"), LARGE: "HD2K"}
RATE_HZ: Final = 15.0
#: Share of a small camera's frames answered beside the large one, at least.
GOAL_ANSWERED: Final = 0.95
#: Most a small camera's median latency may grow beside the large one, ms.
GOAL_LATENCY_MS: Final = 10.0
#: Frames generated per camera (put round and round).
FRAMES: Final = 8
#: After the last put, how long the answers may take, s.
SETTLE_S: Final = 2.0


@dataclass
class Tally:
    """One camera's frames in one phase: when each was put, when its record came back."""

    put_at: dict[int, float] = field(default_factory=dict)  # seq -> perf_counter()
    record_at: dict[int, float] = field(default_factory=dict)
    detect_ms: list[float] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def summary(self) -> dict[str, Any]:
        latencies = [
            (self.record_at[seq] - at) * 1e3
            for seq, at in self.put_at.items()
            if seq in self.record_at
        ]
        put = len(self.put_at)
        return {
            "put": put,
            "answered": len(latencies),
            "answered_share": round(len(latencies) / put, 4) if put else 0.0,
            "latency_median_ms": _pct(latencies, 50),
            "latency_p95_ms": _pct(latencies, 95),
            "detect_median_ms": _pct(self.detect_ms, 50),
        }


def _pct(values: Sequence[float], pct: float) -> float | None:
    if not values:
        return None
    return round(float(np.percentile(np.asarray(values, dtype=np.float64), pct)), 3)


def _flags() -> tuple[str, ...]:
    return (
        "--compressed-input-key",
        "",
        "--tag-key",
        f"{PREFIX}/{{stream}}/tag",
        "--record-key",
        f"{PREFIX}/{{stream}}/tags",
        "--debug-image-key",
        f"{PREFIX}/{{stream}}/debug",
        "--detections-key",
        f"{PREFIX}/{{stream}}/detections",
        "--status-key",
        f"{PREFIX}/status",
    )


class _Bench:
    """The bench's Zenoh peer: a publisher per camera, one subscriber of every record."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.tallies: dict[str, Tally] = {}
        self.publishers = {
            name: session.declare_publisher(
                f"{PREFIX}/{name}/image", congestion_control=zenoh.CongestionControl.BLOCK
            )
            for name in RESOLUTION
        }
        self._records = session.declare_subscriber(f"{PREFIX}/*/tags", self._on_record)

    def _on_record(self, sample: zenoh.Sample) -> None:
        arrived = time.perf_counter()
        name = str(sample.key_expr).split("/")[-2]
        tally = self.tallies.get(name)
        if tally is None:
            return
        record = decode_record(sample.payload.to_bytes())
        with tally.lock:
            tally.record_at.setdefault(int(record["seq"]), arrived)
            tally.detect_ms.append(float(record["timing"]["detect_ms"]))

    def close(self) -> None:
        for entity in (self._records, *self.publishers.values()):
            _undeclare(entity)


def _camera(
    bench: _Bench, name: str, images: Sequence[Image], seconds: float, start: float
) -> None:
    """Put ``images`` round and round at :data:`RATE_HZ` from ``start`` for ``seconds``."""
    publisher, tally = bench.publishers[name], bench.tallies[name]
    payloads = [image.tobytes() for image in images]
    height, width = images[0].shape[:2]
    period = 1.0 / RATE_HZ
    for index in range(int(seconds * RATE_HZ)):
        next_at = start + index * period
        while (left := next_at - time.perf_counter()) > 0:
            time.sleep(left)
        seq = index + 1
        attachment = _attachment(width, height, seq)
        with tally.lock:
            tally.put_at[seq] = time.perf_counter()
        publisher.put(payloads[index % len(payloads)], attachment=attachment)


def _attachment(width: int, height: int, seq: int) -> bytes:
    return RawFrameMeta(width, height, seq=seq, frame_id="bench").to_msgpack()


def phase(
    bench: _Bench, images: dict[str, list[Image]], names: Sequence[str], seconds: float
) -> dict[str, dict[str, Any]]:
    """Every camera of ``names`` at :data:`RATE_HZ` for ``seconds``, each from its thread."""
    bench.tallies = {name: Tally() for name in names}
    start = time.perf_counter() + 0.2
    threads = [
        threading.Thread(target=_camera, args=(bench, name, images[name], seconds, start))
        for name in names
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    deadline = time.monotonic() + SETTLE_S
    while time.monotonic() < deadline and not all(
        len(t.record_at) >= len(t.put_at) for t in bench.tallies.values()
    ):
        time.sleep(0.05)
    return {name: tally.summary() for name, tally in bench.tallies.items()}


def _warm_up(bench: _Bench, images: dict[str, list[Image]], service: ServiceProcess) -> None:
    """One frame per camera answered: every stream made, its outputs declared."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while not query_status(bench.session, f"{PREFIX}/status", 0.5, gather=False):
        service.check()
        if time.monotonic() > deadline:
            raise service.failure("no status in time")
    bench.tallies = {name: Tally() for name in RESOLUTION}
    for name, publisher in bench.publishers.items():
        while not _matching(publisher):
            service.check()
            time.sleep(0.05)
        height, width = images[name][0].shape[:2]
        tally = bench.tallies[name]
        while not tally.record_at:
            publisher.put(images[name][0].tobytes(), attachment=_attachment(width, height, 0))
            wait_until = time.monotonic() + 2.0
            while not tally.record_at and time.monotonic() < wait_until:
                time.sleep(0.02)
            service.check()
            if time.monotonic() > deadline:
                raise service.failure(f"camera {name} not answered")


def _undeclare(entity: Any) -> None:
    """Undeclare a subscriber or publisher (unannotated in zenoh-python)."""
    entity.undeclare()


def _matching(publisher: zenoh.Publisher) -> bool:
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def opencv_bare(images: dict[str, list[Image]]) -> dict[str, float | None]:
    """OpenCV's default on each camera's frames, back to back in this process, ms median."""
    baseline = Baseline(DICTIONARY)
    out: dict[str, float | None] = {}
    for resolution in ("VGA", "HD2K"):
        frames = next(images[n] for n in RESOLUTION if RESOLUTION[n] == resolution)
        out[resolution] = _pct([baseline.run(f)[1] for f in frames * 3], 50)
    return out


def measure(seconds: float, seed: int, flags: Sequence[str] = ()) -> dict[str, Any]:
    by_size = {
        resolution: frames_at(resolution, FRAMES, seed + i)
        for i, resolution in enumerate(("VGA", "HD2K"))
    }
    images = {name: by_size[RESOLUTION[name]] for name in RESOLUTION}
    bare = opencv_bare(images)
    endpoint = loopback_endpoint()
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        bench = _Bench(session)
        service = ServiceProcess(
            "streams", "opencv", endpoint, extra=(*_flags(), *flags), input_key=f"{PREFIX}/*/image"
        )
        try:
            _warm_up(bench, images, service)
            alone = phase(bench, images, SMALL, seconds)
            beside = phase(bench, images, (*SMALL, LARGE), seconds)
            service.check()
        finally:
            service.stop()
            bench.close()
    return {"opencv_bare_ms": bare, "alone": alone, "beside": beside, "rate_hz": RATE_HZ}


def goals(result: dict[str, Any]) -> list[tuple[str, bool]]:
    """Each small camera's goals: answered share and median latency growth."""
    out = []
    for name in SMALL:
        alone, beside = result["alone"][name], result["beside"][name]
        out.append((f"{name} answered >= {GOAL_ANSWERED:.0%}", beside["answered_share"] >= 0.95))
        growth = (beside["latency_median_ms"] or np.inf) - (alone["latency_median_ms"] or 0.0)
        out.append((f"{name} median latency + <= {GOAL_LATENCY_MS:g} ms", growth <= 10.0))
    return out


def report(result: dict[str, Any]) -> str:
    bare = result["opencv_bare_ms"]
    lines = [
        f"cameras at {result['rate_hz']:g} Hz each into one service (a stream each, "
        f"{os.cpu_count()} cores); ms: put -> record, medians unless said",
        f"OpenCV default, bare, same frames: VGA {bare['VGA']} ms, HD2K {bare['HD2K']} ms",
        f"{'phase':<8}{'camera':<7}{'answered':>14}{'median':>9}{'p95':>9}{'detect':>8}",
    ]
    for phase_name in ("alone", "beside"):
        for name, row in result[phase_name].items():
            lines.append(
                f"{phase_name:<8}{name:<7}"
                f"{row['answered']:>6}/{row['put']:<4}{row['answered_share']:>4.0%}"
                f"{_ms(row['latency_median_ms']):>9}{_ms(row['latency_p95_ms']):>9}"
                f"{_ms(row['detect_median_ms']):>8}"
            )
    for text, met in goals(result):
        lines.append(f"goal {text}: {'met' if met else 'MISSED'}")
    lines.append(f"load average {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def main(args: argparse.Namespace) -> int:
    seconds = 4.0 if args.quick else 12.0
    seed = args.seed if args.seed is not None else 2024
    flags = ("-s", str(args.settings)) if args.settings is not None else ()
    result = measure(seconds, seed, flags)
    print(report(result))
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    return 0 if all(met for _, met in goals(result)) else 1
