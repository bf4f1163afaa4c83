"""Camera side: publish frames from a Zenoh shared-memory (SHM) buffer.

A ``bytes`` payload is copied by Zenoh on ``put`` (zenoh 1.x copies large messages into its
own shared memory when SHM is on, the default). A camera that writes its image straight into
a buffer of a Zenoh :class:`zenoh.shm.ShmProvider` skips that copy: the ``put`` hands over a
reference, and a subscriber on the same machine (SHM enabled, the default) reads the pixels
in place (``sample.payload.as_shm()`` is not ``None``). Subscribers elsewhere get an ordinary
copy from Zenoh, so nothing changes for them.

:class:`ShmPutter` owns one provider sized for ``slots`` frames (created at the first frame,
replaced by a larger one when a larger frame comes). Each frame gets its own buffer
(a put consumes it); Zenoh recycles a buffer once every receiver has dropped it. Allocation
uses Zenoh's garbage-collect-then-defragment policy and never blocks: when every slot is still
held (a subscriber hoarding samples), that frame goes as a plain put instead (counted in
``plain_frames``), so the camera never stalls and the pool never grows.

Fallback: where SHM cannot be used (no ``/dev/shm`` in some containers, a size the system
refuses) the putter logs ``event=shm_unavailable`` once and puts plain bytes from then on
(:attr:`ShmPutter.unavailable` holds the reason); with ``strict=True`` it raises
:class:`ShmUnavailableError` instead.

Every camera of this package announces its key with :func:`announce`: a liveliness token at
``@camera/<key>`` while it publishes, so that instances sharing the streams
(``share_group``) learn the stream exists without receiving its frames.

zenoh-python marks this API unstable (``zenoh/shm.pyi``); it is used here as of 1.10: a
``ZShmMut`` accepts ``bytes`` / ``bytearray`` of exactly its size, so a ``memoryview`` payload
is turned into ``bytes`` first (one extra copy).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, Final

import zenoh
import zenoh.shm as zshm

from zenoh_perception.errors import PerceptionError
from zenoh_perception.service.logs import LimitedLog, kv
from zenoh_perception.service.stats import LogGate
from zenoh_perception.sharing import camera_token_key

log = logging.getLogger("zenoh_perception.camera.shm")

#: Frames the provider holds by default: one being written, one in flight, one in the
#: receiver's mailbox and one being processed.
DEFAULT_SLOTS: Final = 4
_PAGE: Final = 4096

Payload = bytes | bytearray | memoryview
#: What :meth:`ShmPutter.load` returns and a publisher's ``put`` takes.
Loaded = zshm.ZShmMut | bytes | bytearray
ProviderFactory = Callable[[int], zshm.ShmProvider]


class ShmUnavailableError(PerceptionError):
    """Zenoh shared memory cannot be used here (no ``/dev/shm``, size refused, ...)."""


def announce(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """Declare that a camera publishes on ``key`` (undeclare it, or leave its ``with`` block,
    when the camera stops; it vanishes with the session anyway)."""
    return session.liveliness().declare_token(camera_token_key(key))


def _slot_bytes(size: int) -> int:
    """Room for one buffer of ``size`` bytes: whole pages plus one for the allocator's own
    bookkeeping (a provider of exactly ``n * size`` bytes holds fewer than ``n`` buffers)."""
    return -(-size // _PAGE) * _PAGE + _PAGE


def _default_provider(size: int) -> zshm.ShmProvider:
    return zshm.ShmProvider.default_backend(size)


def _policy() -> zshm.GarbageCollect:
    # Try; on failure reclaim the buffers receivers have dropped, then defragment; never block.
    return zshm.GarbageCollect(zshm.JustAlloc(), zshm.Defragment())


class ShmPutter:
    """Puts payloads from Zenoh shared memory; one per camera (not thread-safe).

    ``put(publisher, payload, attachment=...)`` loads and puts in one go; a caller that wants
    the write apart from the put (a benchmark timing the put alone) calls :meth:`load` and
    passes its result to ``publisher.put``.
    """

    def __init__(
        self,
        slots: int = DEFAULT_SLOTS,
        *,
        strict: bool = False,
        provider_factory: ProviderFactory = _default_provider,
    ) -> None:
        if slots < 1:
            msg = f"slots must be at least 1, not {slots}"
            raise ValueError(msg)
        self.slots = slots
        self.strict = strict
        self._factory = provider_factory
        self._provider: zshm.ShmProvider | None = None
        self._slot = 0  # bytes per slot of the current provider
        #: Why shared memory is not used (None while it is).
        self.unavailable: str | None = None
        #: Frames loaded into shared memory / passed on as plain bytes.
        self.shm_frames = 0
        self.plain_frames = 0
        self._log = LimitedLog(log, LogGate(5.0))

    @property
    def active(self) -> bool:
        """True unless shared memory turned out to be unavailable."""
        return self.unavailable is None

    def load(self, payload: Payload) -> Loaded:
        """``payload`` in a fresh SHM buffer, ready for one ``put``; the payload itself (as
        ``bytes`` if it was a ``memoryview``) when SHM is unavailable or every slot is held.

        Raises:
            ShmUnavailableError: only with ``strict=True``, when SHM cannot be set up.

        """
        size = len(payload) if not isinstance(payload, memoryview) else payload.nbytes
        buffer = self._alloc(size) if size else None
        data = payload.tobytes() if isinstance(payload, memoryview) else payload
        if buffer is None:
            self.plain_frames += 1
            return data
        buffer[:] = data
        self.shm_frames += 1
        return buffer

    def put(
        self,
        publisher: zenoh.Publisher,
        payload: Payload,
        *,
        attachment: bytes | None = None,
        encoding: zenoh.Encoding | None = None,
    ) -> bool:
        """Put ``payload`` on ``publisher``; True when it went from shared memory."""
        loaded = self.load(payload)
        publisher.put(loaded, encoding=encoding, attachment=attachment)
        return isinstance(loaded, zshm.ZShmMut)

    def summary(self) -> dict[str, Any]:
        """JSON-ready counters: ``shm`` (in use), frames each way and the fallback reason."""
        return {
            "shm": self.active,
            "shm_frames": self.shm_frames,
            "plain_frames": self.plain_frames,
            "unavailable": self.unavailable,
        }

    def _alloc(self, size: int) -> zshm.ZShmMut | None:
        if self.unavailable is not None:
            return None
        if self._provider is None or size > self._slot:
            # A larger frame: a new provider. Buffers of the old one stay valid while held.
            self._provider = self._new_provider(size)
            if self._provider is None:
                return None
        try:
            return self._provider.alloc(size, _policy())
        except zenoh.ZError as err:
            self._log(
                logging.WARNING,
                "exhausted",
                "shm_exhausted",
                slots=self.slots,
                size=size,
                error=err,
            )
            return None

    def _new_provider(self, size: int) -> zshm.ShmProvider | None:
        slot = _slot_bytes(size)
        try:
            provider = self._factory(slot * self.slots)
        except (zenoh.ZError, OSError, ShmUnavailableError) as err:
            self.unavailable = f"{type(err).__name__}: {err}"
            if self.strict:
                msg = f"Zenoh shared memory unavailable: {err}"
                raise ShmUnavailableError(msg) from err
            log.warning(
                "event=shm_unavailable %s",
                kv(bytes=slot * self.slots, fallback="plain_put", error=err),
            )
            return None
        self._slot = slot
        return provider
