"""Files the command line reads whole (settings, Zenoh configuration, manifests): checked
before they are read, so that ``/dev/zero``, a FIFO or a huge file is one error line, not a
hang or a process that grows until it is killed. Pure: no logging."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Final

from zenoh_perception.errors import SettingsError

#: Largest text file the command line reads whole, bytes.
MAX_TEXT_FILE_BYTES: Final = 1 << 20
#: Deepest nesting of brackets a JSON/JSON5/TOML text may have: parsers recurse per level.
MAX_NESTING: Final = 64


def read_text_file(path: Path, what: str, limit: int = MAX_TEXT_FILE_BYTES) -> str:
    """The UTF-8 text of ``path``, a regular file of at most ``limit`` bytes.

    Opened without blocking (a FIFO must not hang) and checked on the open file, so the file
    read is the file checked.

    Raises:
        SettingsError: missing, not a regular file, larger than ``limit``, or not UTF-8; the
            message starts with ``what`` and the path.

    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as err:
        msg = f"cannot read {what} {path}: {err.strerror or err}"
        raise SettingsError(msg) from err
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            msg = f"{what} {path} is not a regular file"
            raise SettingsError(msg)
        data = b""
        while len(data) <= limit:
            chunk = os.read(fd, limit + 1 - len(data))
            if not chunk:
                break
            data += chunk
    except OSError as err:
        msg = f"cannot read {what} {path}: {err.strerror or err}"
        raise SettingsError(msg) from err
    finally:
        os.close(fd)
    if len(data) > limit:
        msg = f"{what} {path} is larger than {limit} bytes"
        raise SettingsError(msg)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        msg = f"{what} {path} is not UTF-8 text: {err}"
        raise SettingsError(msg) from err


def nesting_depth(text: str) -> int:
    """The deepest nesting of ``[`` and ``{`` in a JSON, JSON5 or TOML text, outside strings
    and comments (``//``, ``/* */``, ``#``). A conservative bound, not a parser: checked before
    a recursive parser sees the text."""
    depth = deepest = 0
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in "\"'":
            i += 1
            while i < n and text[i] != c:
                i += 2 if text[i] == "\\" else 1
        elif c == "#" or text.startswith("//", i):
            end = text.find("\n", i)
            i = n if end < 0 else end
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            i = n if end < 0 else end + 1
        elif c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(0, depth - 1)
        i += 1
    return deepest


def check_nesting(text: str, what: str, limit: int = MAX_NESTING) -> None:
    """Refuse a text nested deeper than ``limit``.

    Raises:
        SettingsError: nested deeper than ``limit`` levels; the message names ``what``.

    """
    depth = nesting_depth(text)
    if depth > limit:
        msg = f"{what} is nested {depth} levels deep (at most {limit})"
        raise SettingsError(msg)
