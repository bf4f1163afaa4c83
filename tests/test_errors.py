"""Typed errors: one stable reason per concern, and Zenoh's errors as one readable line."""

from __future__ import annotations

from zenoh_perception import errors
from zenoh_perception.errors import (
    FrameDecodeError,
    PerceptionError,
    ProcessingError,
    zenoh_error_text,
)


def test_every_error_is_a_perception_error() -> None:
    classes = [v for v in vars(errors).values() if isinstance(v, type) and issubclass(v, Exception)]
    assert len(classes) > 10
    assert all(issubclass(cls, PerceptionError) for cls in classes)


def test_frame_rejections_have_distinct_reasons() -> None:
    def subclasses(cls: type[FrameDecodeError]) -> list[type[FrameDecodeError]]:
        found: list[type[FrameDecodeError]] = []
        for sub in cls.__subclasses__():
            found += [sub, *subclasses(sub)]
        return found

    reasons = [
        cls.reason for cls in subclasses(FrameDecodeError) if cls.__module__ == errors.__name__
    ]
    assert len(reasons) == len(set(reasons)) >= 8
    assert all(reason.islower() and " " not in reason for reason in reasons)


def test_a_processing_error_names_its_stage() -> None:
    err = ProcessingError("detect", ValueError("boom"))
    assert (err.stage, err.reason, str(err)) == ("detect", "processing_error", "detect: boom")


def test_zenoh_error_text_drops_rust_locations_and_line_breaks() -> None:
    raw = (
        "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: Address already in use\n"
        "   at /home/runner/.cargo/registry/src/zenoh-link-tcp-1.4.0/src/unicast.rs:344.\n"
        "  at io/zenoh-transport/src/manager.rs:12"
    )
    assert zenoh_error_text(Exception(raw)) == (
        "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: Address already in use"
    )
