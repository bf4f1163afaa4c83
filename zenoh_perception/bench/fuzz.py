"""Bad input: malformed frames through the real running service, then good frames.

``python -m zenoh_perception.bench.fuzz --count 100000``

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

Exit status 0 when every check passes, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import queue
import random
import re
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TextIO

import msgpack
import numpy as np
import zenoh

from zenoh_perception.bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception.bench.flood import (
    Camera,
    Listener,
    frames_of,
    is_idle,
    marker_frame,
    wait_status,
)
from zenoh_perception.bench.processes import start_service, stop_service
from zenoh_perception.errors import FrameDecodeError
from zenoh_perception.service.node import PROCESSING_ERROR
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import (
    MAX_ATTACHMENT_BYTES,
    MAX_DIMENSION,
    check_payload_size,
    decode_image_cdr,
    decode_raw_frame,
    encode_image_cdr,
)
from zenoh_perception.wire.messages import IMAGE_TYPE, TYPESTORE

OK: Final = "ok"

_CHANNELS: Final = {"bgra8": 4, "rgba8": 4, "bgr8": 3, "rgb8": 3, "mono8": 1}
_ABSURD_INTS: Final = (
    0,
    -1,
    -7,
    1,
    2,
    MAX_DIMENSION,
    MAX_DIMENSION + 1,
    65535,
    2**31 - 1,
    2**31,
    -(2**31),
    2**32 - 1,
    2**32,
    2**53,
    2**63 - 1,
    -(2**63),
    2**64 - 1,
)
_WRONG_TYPES: Final[tuple[object, ...]] = (
    "640",
    "",
    6.4,
    float("nan"),
    float("inf"),
    True,
    False,
    None,
    [640],
    {"w": 640},
    b"\x00\x01",
)
_ENCODINGS: Final = (
    "",
    "yuv422",
    "16UC1",
    "32FC1",
    "bayer_rggb8",
    "BGRA8",
    "bgra8 ",
    "bgra16",
    "mono16",
    "nv12",
    "\x00",
    "é",
    "x" * 300,
    "bgra8\x00",
)
_FIELDS: Final = ("width", "height", "encoding", "step", "stamp_ns", "frame_id", "seq")


@dataclass(frozen=True, slots=True)
class Case:
    """One payload to send: its generator's name and what Zenoh carries."""

    kind: str
    payload: bytes
    attachment: bytes | None


# -- generators: pure functions of a random.Random -----------------------------------------------


def _rand_bytes(rng: random.Random, low: int, high: int) -> bytes:
    return rng.randbytes(rng.randint(low, high))


def _small_image(rng: random.Random) -> tuple[np.ndarray[Any, np.dtype[np.uint8]], str]:
    encoding = rng.choice(tuple(_CHANNELS))
    width, height = rng.randint(1, 24), rng.randint(1, 16)
    shape: tuple[int, ...] = (height, width, _CHANNELS[encoding])
    if _CHANNELS[encoding] == 1:
        shape = (height, width)
    pixels = np.frombuffer(rng.randbytes(int(np.prod(shape))), dtype=np.uint8).reshape(shape)
    return pixels, encoding


def _valid_cdr(rng: random.Random) -> bytes:
    pixels, encoding = _small_image(rng)
    row = pixels.shape[1] * _CHANNELS[encoding]
    step = row + rng.choice((0, 0, 0, 1, 3, 8))
    stamp = rng.randint(0, 2**40)
    frame_id = rng.choice(("", "zed_left", "x" * rng.randint(0, 40)))
    return bytes(encode_image_cdr(pixels, encoding, stamp_ns=stamp, frame_id=frame_id, step=step))


def _valid_meta(rng: random.Random) -> tuple[dict[str, object], int]:
    """A valid attachment map and the payload size it describes."""
    encoding = rng.choice(tuple(_CHANNELS))
    width, height = rng.randint(1, 24), rng.randint(1, 16)
    row = width * _CHANNELS[encoding]
    fields: dict[str, object] = {"width": width, "height": height, "encoding": encoding}
    step = row
    if rng.random() < 0.3:
        step = row + rng.randint(1, 8)
        fields["step"] = step
    if rng.random() < 0.5:
        fields["seq"] = rng.randint(0, 2**31)
    if rng.random() < 0.5:
        fields["stamp_ns"] = rng.randint(0, 2**62)
    if rng.random() < 0.3:
        fields["frame_id"] = "zed_left"
    return fields, step * height


def _pack(value: object) -> bytes:
    packed: bytes = msgpack.packb(value, use_bin_type=True)
    return packed


def _flip_bits(rng: random.Random, data: bytes, max_flips: int = 8) -> bytes:
    buf = bytearray(data)
    if not buf:
        return bytes(buf)
    for _ in range(rng.randint(1, max_flips)):
        i = rng.randrange(len(buf))
        buf[i] ^= 1 << rng.randrange(8)
    return bytes(buf)


def gen_random_bytes(rng: random.Random) -> Case:
    return Case("random_bytes", _rand_bytes(rng, 0, 2048), None)


def gen_random_attached(rng: random.Random) -> Case:
    return Case("random_attachment", _rand_bytes(rng, 0, 512), _rand_bytes(rng, 1, 96))


def gen_cdr_truncated(rng: random.Random) -> Case:
    cdr = _valid_cdr(rng)
    return Case("cdr_truncated", cdr[: rng.randrange(len(cdr))], None)


def gen_cdr_bitflip(rng: random.Random) -> Case:
    cdr = _valid_cdr(rng)
    # Flip bits in the header / fixed fields most of the time (pixels flips decode fine).
    head = min(len(cdr), 64)
    if rng.random() < 0.8:
        return Case("cdr_bitflip", _flip_bits(rng, cdr[:head]) + cdr[head:], None)
    return Case("cdr_bitflip", _flip_bits(rng, cdr), None)


def gen_cdr_extended(rng: random.Random) -> Case:
    cdr = _valid_cdr(rng)
    return Case("cdr_trailing_bytes", cdr + _rand_bytes(rng, 1, 64), None)


def gen_cdr_inconsistent(rng: random.Random) -> Case:
    """Well-formed CDR whose width/height/step/encoding/data disagree or are absurd."""
    types = TYPESTORE.types
    u32 = (0, 1, 2, 7, 16, MAX_DIMENSION, MAX_DIMENSION + 1, 2**31, 2**32 - 1)
    image = types[IMAGE_TYPE](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](
                sec=rng.choice((0, 1, 2**31 - 1, -(2**31))), nanosec=rng.choice((0, 2**32 - 1))
            ),
            frame_id=rng.choice(("", "cam", "\u00e9" * 10)),
        ),
        height=rng.choice(u32),
        width=rng.choice(u32),
        encoding=rng.choice((*_CHANNELS, *_ENCODINGS)),
        is_bigendian=rng.choice((0, 1, 255)),
        step=rng.choice(u32),
        data=np.frombuffer(_rand_bytes(rng, 0, 1024), dtype=np.uint8),
    )
    return Case("cdr_inconsistent", bytes(TYPESTORE.serialize_cdr(image, IMAGE_TYPE)), None)


def gen_cdr_header(rng: random.Random) -> Case:
    cdr = _valid_cdr(rng)
    header = rng.choice((b"\x00\x00\x00\x00", b"\x00\x02\x00\x00", b"\xff\xff\xff\xff"))
    return Case("cdr_bad_encapsulation", header + cdr[4:], None)


def gen_raw_absurd_dims(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    for key in rng.sample(("width", "height", "step"), rng.randint(1, 3)):
        fields[key] = rng.choice(_ABSURD_INTS)
    return Case("raw_absurd_dimensions", rng.randbytes(min(size, 4096)), _pack(fields))


def gen_raw_wrong_types(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    for key in rng.sample(_FIELDS, rng.randint(1, 3)):
        fields[key] = rng.choice(_WRONG_TYPES)
    return Case("raw_wrong_types", rng.randbytes(size), _pack(fields))


def gen_raw_unknown_encoding(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    fields["encoding"] = rng.choice(_ENCODINGS)
    return Case("raw_unknown_encoding", rng.randbytes(size), _pack(fields))


def gen_raw_bad_step(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    row = int(str(fields["width"])) * _CHANNELS[str(fields["encoding"])]
    fields["step"] = rng.choice(
        (-1, 0, row - 1, row + MAX_DIMENSION + 1, 2**31, 2**63 - 1, -(2**63), 2**64 - 1)
    )
    return Case("raw_bad_step", rng.randbytes(size), _pack(fields))


def gen_raw_size_mismatch(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    delta = rng.choice((-size, -1, 1, 2, 7, size))
    return Case("raw_size_mismatch", rng.randbytes(max(0, size + delta)), _pack(fields))


def gen_raw_bad_fields(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    choice = rng.randrange(6)
    if choice == 0:
        fields["stamp_ns"] = rng.choice((-1, -(2**63)))
    elif choice == 1:
        fields["frame_id"] = "f" * rng.choice((257, 1000))
    elif choice == 2:
        del fields[rng.choice(("width", "height"))]
    elif choice == 3:
        fields[rng.choice((1, b"x", 2.5, "\u00e9"))] = rng.choice(_WRONG_TYPES)  # type: ignore[index]
    elif choice == 4:
        fields["seq"] = rng.choice(("1", -1.5, [1]))
    else:
        fields = {key.upper(): value for key, value in fields.items()}
    return Case("raw_bad_fields", rng.randbytes(size), _pack(fields))


def gen_raw_not_map(rng: random.Random) -> Case:
    value = rng.choice(([1, 2, 3], 7, "bgra8", None, b"\x00" * 8, 1.5, [[{"width": 1}]]))
    return Case("raw_attachment_not_map", rng.randbytes(rng.randint(0, 64)), _pack(value))


def gen_raw_bad_msgpack(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    packed = _pack(fields)
    choice = rng.randrange(5)
    if choice == 0:
        attachment = packed[: rng.randrange(1, len(packed))]
    elif choice == 1:
        attachment = packed + _rand_bytes(rng, 1, 8)
    elif choice == 2:
        attachment = _pack({**fields, "pad": "x" * (MAX_ATTACHMENT_BYTES + rng.randint(0, 64))})
    elif choice == 3:
        depth = rng.choice((100, 1000, 2000))
        attachment = b"\x91" * depth + b"\xc0"
    else:
        attachment = b"\xdf\xff\xff\xff\xff"  # a map announcing 4 billion entries
    return Case("raw_bad_msgpack", rng.randbytes(size), attachment)


def gen_raw_bitflip(rng: random.Random) -> Case:
    fields, size = _valid_meta(rng)
    return Case("raw_bitflip_attachment", rng.randbytes(size), _flip_bits(rng, _pack(fields), 3))


def gen_raw_empty(rng: random.Random) -> Case:
    fields, _size = _valid_meta(rng)
    return Case("raw_empty_payload", b"", _pack(fields))


GENERATORS: Final[tuple[Callable[[random.Random], Case], ...]] = (
    gen_random_bytes,
    gen_random_attached,
    gen_cdr_truncated,
    gen_cdr_bitflip,
    gen_cdr_extended,
    gen_cdr_inconsistent,
    gen_cdr_header,
    gen_raw_absurd_dims,
    gen_raw_wrong_types,
    gen_raw_unknown_encoding,
    gen_raw_bad_step,
    gen_raw_size_mismatch,
    gen_raw_bad_fields,
    gen_raw_not_map,
    gen_raw_bad_msgpack,
    gen_raw_bitflip,
    gen_raw_empty,
)


def cases(seed: int, count: int) -> Iterator[Case]:
    """``count`` malformed payloads, cycling through every generator (deterministic)."""
    rng = random.Random(seed)
    for i in range(count):
        yield GENERATORS[i % len(GENERATORS)](rng)


def expected_outcome(case: Case) -> str:
    """What the service should do with ``case``: "ok" or the rejection reason.

    Runs the project's decoders, as the service does. Any exception other than
    FrameDecodeError propagates (with the payload's kind in the traceback): that is a bug.
    """
    limits = Settings()
    try:
        check_payload_size(len(case.payload), limits.max_frame_bytes)
        if case.attachment is not None:
            decode_raw_frame(case.payload, case.attachment, max_pixels=limits.max_frame_pixels)
        else:
            decode_image_cdr(case.payload, max_pixels=limits.max_frame_pixels)
    except FrameDecodeError as err:
        return err.reason
    return OK


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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m zenoh_perception.bench.fuzz", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--count", type=int, default=100_000, help="payloads (default 100000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=2000.0, help="payloads/s; 0: unpaced")
    parser.add_argument("--json", type=Path, default=None, help="also write the report here")
    args = parser.parse_args(argv)
    report = run_fuzz(args.count, seed=args.seed, rate=args.rate, progress=sys.stderr)
    print(format_report(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report.as_dict(), indent=2) + "\n", encoding="utf-8")
    return 1 if report.problems() else 0


if __name__ == "__main__":
    sys.exit(main())
