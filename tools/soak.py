"""Soak: the real service (``zenoh-perception run`` subprocess) against a steady camera.

``python -m tools.soak --duration 600 --rate 60 --resolution HD720``

Publishes raw BGRA frames (ArUco markers at moving positions) at ``--rate`` Hz on loopback,
samples the service process's RSS, thread count and open file descriptors from /proc, measures
the end-to-end latency (frame put -> its ``perception/tags`` record received), and at the end
reads the service's own counters and latency percentiles from ``perception/status``.

Exit status: 0 when, after the warm-up, RSS grew less than ``--max-rss-growth-pct`` and neither
threads nor file descriptors grew; 1 when a limit is exceeded; 2 when the service failed
(did not start, stopped answering, or did not exit cleanly).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

import zenoh

from tools.rig import (
    Camera,
    MarkerFrame,
    ProcSample,
    marker_frame,
    percentile,
    proc_sample,
    wait_status,
)
from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.wire.records import decode_record
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import frames_of, is_idle, start_service, stop_service

_SEQ_SLOTS = 1 << 14  # put times kept for latency matching (~4.5 min at 60 Hz)


@dataclass(frozen=True, slots=True)
class SoakConfig:
    duration_s: float = 600.0
    rate_hz: float = 60.0
    resolution: str = "HD720"
    warmup_s: float | None = None  # default: min(60 s, duration / 5)
    sample_s: float = 1.0
    max_rss_growth_pct: float = 5.0
    startup_timeout_s: float = 60.0

    @property
    def effective_warmup_s(self) -> float:
        if self.warmup_s is not None:
            return self.warmup_s
        return min(60.0, self.duration_s / 5)


@dataclass(slots=True)
class SoakReport:
    config: dict[str, Any]
    start: ProcSample  # first sample of the service process
    baseline: ProcSample  # at the end of the warm-up
    end: ProcSample  # last sample
    peak_rss_kib: int
    frames_sent: int
    late_puts: int  # puts more than one period behind schedule (publisher overloaded)
    answered: int  # records received for frames of this run
    e2e_latency_ms: dict[str, float]  # put -> record received, this side
    service: dict[str, Any]  # the service's status at the end
    exit_code: int | None  # of the service after SIGTERM
    exit_s: float | None
    samples: list[tuple[float, int, int, int]] = field(default_factory=list)

    @property
    def rss_growth_pct(self) -> float:
        return 100.0 * (self.end.rss_kib - self.baseline.rss_kib) / max(self.baseline.rss_kib, 1)

    def problems(self) -> list[str]:
        limit = float(self.config["max_rss_growth_pct"])
        out: list[str] = []
        if self.rss_growth_pct >= limit:
            out.append(f"RSS grew {self.rss_growth_pct:.2f}% after the warm-up (limit {limit}%)")
        if self.end.threads > self.baseline.threads:
            out.append(f"threads grew {self.baseline.threads} -> {self.end.threads}")
        if self.end.fds > self.baseline.fds:
            out.append(f"file descriptors grew {self.baseline.fds} -> {self.end.fds}")
        return out

    def failures(self) -> list[str]:
        out: list[str] = []
        if self.answered == 0 or frames_of(self.service)["processed"] == 0:
            out.append("the service processed no frame")
        if self.exit_code != 0:
            out.append(f"the service exited with {self.exit_code} after SIGTERM")
        return out

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["rss_growth_pct"] = round(self.rss_growth_pct, 3)
        data["problems"] = self.problems()
        data["failures"] = self.failures()
        return data


class _Latencies:
    """Matches records to put times by seq; keeps every end-to-end latency (ms)."""

    def __init__(self) -> None:
        self._put_at = [0.0] * _SEQ_SLOTS
        self._put_seq = [-1] * _SEQ_SLOTS
        self.values: list[float] = []
        self._lock = threading.Lock()

    def sent(self, seq: int, at: float) -> None:
        with self._lock:
            self._put_at[seq % _SEQ_SLOTS] = at
            self._put_seq[seq % _SEQ_SLOTS] = seq

    def on_record(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        try:
            seq = decode_record(sample.payload.to_bytes()).get("seq")
        except MessageDecodeError:
            return
        if not isinstance(seq, int) or seq < 0:
            return
        with self._lock:
            if self._put_seq[seq % _SEQ_SLOTS] == seq:
                self.values.append((now - self._put_at[seq % _SEQ_SLOTS]) * 1e3)


def _frames(resolution: str, count: int = 8) -> list[MarkerFrame]:
    """Markers of changing id, size and position (the detector's work varies a little)."""
    width, height = RESOLUTIONS[resolution]
    frames = []
    for i in range(count):
        side = max(60, min(width, height) // (3 + i % 3))
        margin = side // 6 + 1
        x = margin + (width - side - 2 * margin) * i // max(count - 1, 1)
        y = margin + (height - side - 2 * margin) * ((i * 3) % count) // max(count - 1, 1)
        frames.append(marker_frame(width, height, i % 50, side=side, origin=(x, y), seed=i))
    return frames


def run_soak(config: SoakConfig, *, progress: TextIO | None = None) -> SoakReport:
    """Run the service and the camera for ``config.duration_s`` seconds; see the module doc.

    Raises:
        TimeoutError: the service did not answer its status queryable in time.

    """
    endpoint = loopback_endpoint()
    frames = _frames(config.resolution)
    warmup = config.effective_warmup_s
    with tempfile.TemporaryFile("w+") as log:
        proc = start_service(endpoint, log, "--stats-interval-s", "0")
        exit_code: int | None = None
        exit_s: float | None = None
        try:
            with zenoh.open(loopback_config(connect=[endpoint])) as session:
                wait_status(session, lambda s: True, timeout=config.startup_timeout_s, what="up")
                latencies = _Latencies()
                subscriber = session.declare_subscriber("perception/tags", latencies.on_record)
                camera = Camera(session)
                camera.wait_matched()
                samples: list[tuple[float, int, int, int]] = []
                start = time.monotonic()
                next_sample = start
                period = 1.0 / config.rate_hz
                seq = late = 0
                baseline: ProcSample | None = None
                while (now := time.monotonic()) - start < config.duration_s:
                    if now >= next_sample:
                        sample = proc_sample(proc.pid)
                        samples.append((now - start, sample.rss_kib, sample.threads, sample.fds))
                        if baseline is None and now - start >= warmup:
                            baseline = sample
                        next_sample += config.sample_s
                        if progress is not None and len(samples) % 30 == 1:
                            print(
                                f"t={now - start:6.0f}s rss={sample.rss_kib / 1024:.1f}MiB "
                                f"threads={sample.threads} fds={sample.fds} sent={seq}",
                                file=progress,
                                flush=True,
                            )
                    due = start + seq * period
                    if now < due:
                        time.sleep(min(due - now, max(next_sample - now, 0.0)))
                        continue
                    if now - due > period:
                        late += 1
                    latencies.sent(seq, time.monotonic())
                    camera.put(frames[seq % len(frames)], seq)
                    seq += 1
                if proc.poll() is not None:
                    msg = f"the service exited with {proc.returncode} during the soak"
                    raise ChildProcessError(msg)
                last = proc_sample(proc.pid)
                samples.append((time.monotonic() - start, last.rss_kib, last.threads, last.fds))
                # Let the last frames through (received, and none still in the worker), then
                # read the service's own view.
                service = wait_status(
                    session,
                    lambda s: frames_of(s)["received"] >= seq and is_idle(s),
                    timeout=10.0,
                    what="every frame received and handled",
                )
                camera.close()
                subscriber.undeclare()  # type: ignore[no-untyped-call]
            exit_code, exit_s = stop_service(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if progress is not None and exit_code != 0:
                log.seek(0)
                print(log.read()[-4000:], file=progress)
    first = ProcSample(samples[0][1], samples[0][2], samples[0][3])
    return SoakReport(
        config={**asdict(config), "warmup_s": warmup},
        start=first,
        baseline=baseline if baseline is not None else first,
        end=last,
        peak_rss_kib=max(s[1] for s in samples),
        frames_sent=seq,
        late_puts=late,
        answered=len(latencies.values),
        e2e_latency_ms={
            "p50": round(percentile(latencies.values, 50), 3),
            "p99": round(percentile(latencies.values, 99), 3),
            "max": round(max(latencies.values, default=0.0), 3),
        },
        service=service,
        exit_code=exit_code,
        exit_s=exit_s,
        samples=samples,
    )


def format_report(report: SoakReport) -> str:
    f = frames_of(report.service)
    lat = report.service["latency_ms"]
    c = report.config
    lines = [
        f"soak: {c['duration_s']:g} s at {c['rate_hz']:g} Hz {c['resolution']} "
        f"(warm-up {c['warmup_s']:g} s)",
        f"RSS      start {report.start.rss_kib / 1024:.1f} MiB, after warm-up "
        f"{report.baseline.rss_kib / 1024:.1f} MiB, end {report.end.rss_kib / 1024:.1f} MiB "
        f"(growth {report.rss_growth_pct:+.2f}%), peak {report.peak_rss_kib / 1024:.1f} MiB",
        f"threads  start {report.start.threads}, after warm-up {report.baseline.threads}, "
        f"end {report.end.threads}",
        f"fds      start {report.start.fds}, after warm-up {report.baseline.fds}, "
        f"end {report.end.fds}",
        f"frames   sent {report.frames_sent} (late puts {report.late_puts}), received "
        f"{f['received']}, processed {f['processed']}, dropped {f['dropped']}, rejected "
        f"{f['rejected']}",
        f"latency  service p50 {lat['p50']:.2f} ms p99 {lat['p99']:.2f} ms (last 1000 frames); "
        f"end-to-end p50 {report.e2e_latency_ms['p50']:.2f} ms p99 "
        f"{report.e2e_latency_ms['p99']:.2f} ms ({report.answered} records)",
        f"exit     SIGTERM -> code {report.exit_code} in {report.exit_s or 0.0:.2f} s",
    ]
    lines += [f"PROBLEM: {p}" for p in report.problems()]
    lines += [f"FAILURE: {p}" for p in report.failures()]
    lines.append("PASS" if not report.problems() and not report.failures() else "FAIL")
    return "\n".join(lines)


def main(config: SoakConfig, *, json_path: Path | None = None, quiet: bool = False) -> int:
    """Soak the service and print the report (also to ``json_path``); the exit status."""
    try:
        report = run_soak(config, progress=None if quiet else sys.stderr)
    except (TimeoutError, ChildProcessError, zenoh.ZError) as err:
        print(f"soak: the service failed: {err}", file=sys.stderr)
        return 2
    print(format_report(report))
    if json_path is not None:
        json_path.write_text(json.dumps(report.as_dict(), indent=2) + "\n", encoding="utf-8")
    if report.failures():
        return 2
    return 1 if report.problems() else 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        prog="python -m tools.soak", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("--rate", type=float, default=60.0, help="frames per second (default 60)")
    parser.add_argument("--resolution", choices=sorted(RESOLUTIONS), default="HD720")
    parser.add_argument("--warmup", type=float, default=None, help="default min(60, duration/5)")
    parser.add_argument("--max-rss-growth-pct", type=float, default=5.0)
    parser.add_argument("--json", type=Path, default=None, help="also write the report here")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args()
    if args.duration <= 0 or args.rate <= 0:
        parser.error("--duration and --rate must be positive")
    config = SoakConfig(
        duration_s=args.duration,
        rate_hz=args.rate,
        resolution=args.resolution,
        warmup_s=args.warmup,
        max_rss_growth_pct=args.max_rss_growth_pct,
    )
    sys.exit(main(config, json_path=args.json, quiet=args.quiet))
