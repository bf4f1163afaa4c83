"""zenoh-perception: ArUco tag perception over Zenoh, ROS 2 compatible on the wire.

Architecture (pure parts first, Zenoh last):

- ``frames``     decode camera frames (raw + msgpack attachment, or sensor_msgs/Image CDR)
- ``detection``  find ArUco markers in a grey image
- ``geometry``   per-tag centre, area, closeness metric
- ``selection``  pick the one tag a frame reports (closest / centre policy)
- ``messages``   the ROS 2 wire types (StarterProjectTag, Image, CompressedImage) via rosbags
- ``records``    encode/decode the ``tag`` CDR and the ``perception/tags`` msgpack record
- ``pipeline``   frame -> detections -> observations -> selection, no I/O
- ``mailbox``    latest-frame-wins hand-off between Zenoh's callback thread and the worker
- ``stats``      counters, latency percentiles, rate-limited log gate
- ``settings``   the one frozen settings dataclass and its TOML file / flag overrides
- ``service``    the thin Zenoh wiring (subscriber, worker, publishers, status, liveliness)
- ``cli``        argument parsing only
"""

__version__ = "0.1.0"
