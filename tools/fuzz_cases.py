"""Malformed camera payloads for the fuzz script, by kind, each with the outcome the project's
own decoders predict for it (the fuzz's oracle)."""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Final

import msgpack
import numpy as np

from zenoh_perception.errors import FrameDecodeError
from zenoh_perception.settings.sections import Limits
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
    limits = Limits()
    try:
        check_payload_size(len(case.payload), limits.max_frame_bytes)
        if case.attachment is not None:
            decode_raw_frame(case.payload, case.attachment, max_pixels=limits.max_frame_pixels)
        else:
            decode_image_cdr(case.payload, max_pixels=limits.max_frame_pixels)
    except FrameDecodeError as err:
        return err.reason
    return OK
