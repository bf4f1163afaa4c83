"""The project's own stress tools: they drive the service the way a user's camera would, and
import :mod:`zenoh_perception` like any user. Not installed with the package; run each from the
repository root with ``python -m tools.<name>`` (tools/README.md)."""
