"""Bad input: malformed frames through the real running service, then good frames.

``python -m tools.fuzz --count 100000``

Starts ``zenoh-perception run`` (a subprocess, loopback, no multicast scouting), publishes
``--count`` malformed payloads on ``zed/left/image`` -- random bytes, truncated and bit-flipped
``sensor_msgs/Image`` CDR, well-formed CDR with inconsistent fields, raw frames whose msgpack
attachment is garbage, not a map, oversized, or has absurd sizes, wrong types, unknown
encodings, negative dimensions, huge steps... -- and then checks that the service:

- is alive (the process runs, ``perception/status`` answers);
- accounted for every payload: ``received == sent`` and ``received == processed + dropped +
  rejected``, and for each rejection reason the service counted at most what the project's own
  decoders (run here as the oracle) predict for the payloads sent, with no other reason;
- never failed to process a payload that decodes (``processing_error``: a detector bug);
- logged no traceback;
- still answers a good raw frame and a good CDR frame with the right tag and centre.

Zenoh is told to block rather than drop (so ``received == sent``); the service's mailbox keeps
only the newest payload, so at high rates some payloads are dropped before decoding (counted).

Exit status 0 when every check passes, 1 otherwise. The payloads and their predicted
outcomes are made by :mod:`tools.fuzz_cases`.
"""

from __future__ import annotations

import argparse
import json
import queue
import re
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import zenoh

from tools.fuzz_cases import GENERATORS, OK, cases, expected_outcome
from tools.rig import Camera, Listener, marker_frame, wait_status
from zenoh_perception.service.node import PROCESSING_ERROR
from zenoh_perception.wire.frames import encode_image_cdr
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import frames_of, is_idle, start_service, stop_service

# -- the run ---------------------------------------------------------------------------------------


@dataclass(slots=True)
class FuzzReport:
    sent: int = 0
    send_s: float = 0.0
    by_kind: Counter[str] = field(default_factory=Counter)
    expected: Counter[str] = field(default_factory=Counter)  # reason (or "ok") -> payloads
    status: dict[str, Any] = field(default_factory=dict)
    good_answers: list[dict[str, Any]] = field(default_factory=list)
    rejected_log_lines: int = 0
    tracebacks: int = 0
    alive: bool = False
    exit_code: int | None = None

    @property
    def rate(self) -> float:
        return self.sent / self.send_s if self.send_s > 0 else 0.0

    def problems(self) -> list[str]:
        out: list[str] = []
        if not self.alive:
            out.append("the service is not alive after the fuzz")
        if not self.status:
            out.append("no status after the fuzz")
            return out
        f = frames_of(self.status)
        by_reason: dict[str, int] = self.status["rejected_by_reason"]
        good = len(self.good_answers)
        if f["received"] != self.sent + good:
            out.append(f"received {f['received']} != sent {self.sent} + {good} good")
        if not is_idle(self.status):
            out.append(f"frames unaccounted for: {f}")
        if sum(by_reason.values()) != f["rejected"]:
            out.append(f"rejections by reason {by_reason} do not add up to {f['rejected']}")
        failed = by_reason.get(PROCESSING_ERROR, 0)
        if failed:
            out.append(f"the detector failed on {failed} valid frame(s) ({PROCESSING_ERROR})")
        for reason, count in by_reason.items():
            if reason != PROCESSING_ERROR and count > self.expected.get(reason, 0):
                out.append(
                    f"{count} rejections for {reason!r}, only {self.expected.get(reason, 0)} "
                    "payloads should have been"
                )
        if f["processed"] + failed > self.expected.get(OK, 0) + good:
            out.append(f"processed {f['processed']} > {self.expected.get(OK, 0)} valid + {good}")
        if self.tracebacks:
            out.append(f"{self.tracebacks} traceback(s) in the service log")
        for answer in self.good_answers:
            if not answer["ok"]:
                out.append(f"good {answer['source']} frame answered wrongly: {answer}")
        if self.exit_code not in (None, 0):
            out.append(f"the service exited with {self.exit_code} after SIGTERM")
        return out

    def as_dict(self) -> dict[str, Any]:
        return {
            "sent": self.sent,
            "send_s": round(self.send_s, 3),
            "rate_per_s": round(self.rate, 1),
            "by_kind": dict(self.by_kind),
            "expected": dict(self.expected),
            "status": self.status,
            "good_answers": self.good_answers,
            "rejected_log_lines": self.rejected_log_lines,
            "tracebacks": self.tracebacks,
            "alive": self.alive,
            "exit_code": self.exit_code,
            "problems": self.problems(),
        }


def _check_good(
    camera: Camera, listener: Listener, source: str, seq: int, timeout: float
) -> dict[str, Any]:
    """Send one good frame (raw or CDR) with tag 7 and check its record and tag."""
    frame = marker_frame(320, 240, 7, side=96, origin=(40, 60))
    listener.drain()
    if source == "raw":
        camera.put(frame, seq)
    else:
        pixels = np.frombuffer(frame.payload, dtype=np.uint8).reshape(240, 320, 4)
        camera.put_raw(bytes(encode_image_cdr(pixels, "bgra8", stamp_ns=seq)), None)
    deadline = time.monotonic() + timeout
    record: dict[str, Any] | None = None
    tag_id: int | None = None
    while (left := deadline - time.monotonic()) > 0 and (record is None or tag_id != 7):
        try:
            answer = listener.get(left)
        except queue.Empty:
            break
        if answer.tag is not None:
            tag_id = answer.tag.tag_id
        elif answer.record is not None and (
            answer.record.get("seq") == seq or answer.record.get("stamp_ns") == seq
        ):
            record = answer.record
    selected = record["selected"] if record is not None else {}
    x, y = frame.center
    ok = (
        record is not None
        and tag_id == 7
        and selected.get("tag_id") == 7
        and abs(float(selected.get("x_tag_center_pixel", -1e9)) - x) <= 1.0
        and abs(float(selected.get("y_tag_center_pixel", -1e9)) - y) <= 1.0
    )
    return {"source": source, "ok": ok, "tag_id": tag_id, "selected": selected}


def run_fuzz(
    count: int,
    *,
    seed: int = 0,
    rate: float = 2000.0,
    timeout_s: float = 60.0,
    progress: TextIO | None = None,
) -> FuzzReport:
    """Start the service, send ``count`` malformed payloads at ``rate``/s (0: no pacing)."""
    report = FuzzReport()
    endpoint = loopback_endpoint()
    with tempfile.TemporaryFile("w+") as log:
        proc = start_service(endpoint, log, "--stats-interval-s", "0", "--log-interval-s", "1")
        try:
            with zenoh.open(loopback_config(connect=[endpoint])) as session:
                wait_status(session, lambda s: True, timeout=timeout_s, what="up")
                camera = Camera(session)
                listener = Listener(session)
                camera.wait_matched()
                start = time.monotonic()
                for i, case in enumerate(cases(seed, count)):
                    report.expected[expected_outcome(case)] += 1
                    report.by_kind[case.kind] += 1
                    if rate > 0:
                        delay = start + i / rate - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    camera.put_raw(case.payload, case.attachment)
                    report.sent += 1
                    if progress is not None and report.sent % 20000 == 0:
                        print(f"sent {report.sent}", file=progress, flush=True)
                report.send_s = time.monotonic() - start
                wait_status(
                    session,
                    lambda s: frames_of(s)["received"] >= report.sent and is_idle(s),
                    timeout=timeout_s,
                    what="every payload received and handled",
                )
                seq = 4_000_000
                for source in ("raw", "cdr"):
                    seq += 1
                    report.good_answers.append(_check_good(camera, listener, source, seq, 10.0))
                report.status = wait_status(
                    session,
                    lambda s: frames_of(s)["received"] >= report.sent + 2 and is_idle(s),
                    timeout=timeout_s,
                    what="good frames handled",
                )
                report.alive = proc.poll() is None
                listener.close()
                camera.close()
            report.exit_code, _exit_s = stop_service(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            log.seek(0)
            text = log.read()
        report.rejected_log_lines = len(re.findall(r"event=rejected ", text))
        report.tracebacks = text.count("Traceback")
        if progress is not None and report.tracebacks:
            print(text[-4000:], file=progress)
    return report


def format_report(report: FuzzReport) -> str:
    f = frames_of(report.status) if report.status else {}
    by_reason: dict[str, int] = report.status.get("rejected_by_reason", {})
    lines = [
        f"fuzz: sent {report.sent} malformed payloads in {report.send_s:.1f} s "
        f"({report.rate:.0f}/s), {len(GENERATORS)} generators",
        f"service: {f}",
        "rejections by reason (service / predicted by the decoders):",
    ]
    reasons = sorted(set(by_reason) | {k for k in report.expected if k != OK})
    lines += [
        f"  {reason:24s} {by_reason.get(reason, 0):8d} / {report.expected.get(reason, 0):8d}"
        for reason in reasons
    ]
    lines.append(
        f"  {'(valid, processed)':24s} {f.get('processed', 0):8d} / "
        f"{report.expected.get(OK, 0):8d} (+{len(report.good_answers)} good frames)"
    )
    lines.append(f"'event=rejected' log lines: {report.rejected_log_lines} (rate-limited)")
    for answer in report.good_answers:
        lines.append(f"good {answer['source']} frame: {'OK' if answer['ok'] else 'WRONG'}")
    lines += [f"PROBLEM: {p}" for p in report.problems()]
    lines.append("PASS" if not report.problems() else "FAIL")
    return "\n".join(lines)


def main(count: int, *, seed: int = 0, rate: float = 2000.0, json_path: Path | None = None) -> int:
    """Fuzz the service and print the report (also to ``json_path``); 1 when a check fails."""
    report = run_fuzz(count, seed=seed, rate=rate, progress=sys.stderr)
    print(format_report(report))
    if json_path is not None:
        json_path.write_text(json.dumps(report.as_dict(), indent=2) + "\n", encoding="utf-8")
    return 1 if report.problems() else 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        prog="python -m tools.fuzz", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--count", type=int, default=100_000, help="payloads (default 100000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=2000.0, help="payloads/s; 0: unpaced")
    parser.add_argument("--json", type=Path, default=None, help="also write the report here")
    args = parser.parse_args()
    sys.exit(main(args.count, seed=args.seed, rate=args.rate, json_path=args.json))
