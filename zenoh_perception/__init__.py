"""zenoh-perception: ArUco tag perception over Zenoh, ROS 2 compatible on the wire.

One package per concern, pure parts first and Zenoh last; a module imports only from its own
layer and the layers above it in this list:

- ``errors``, ``resolutions``  typed errors; the named camera resolutions
- ``tags``      what a detection means: centre, closeness, pose, the one tag a frame reports
- ``wire``      bytes to objects and back: camera frames, ROS 2 types, tag CDR, record, debug image
- ``detect``    markers in a grey image (OpenCV's ArUco detector decides every one)
- ``settings``  the frozen settings, a section per component, its TOML file and its flags
- ``pipeline``  frame -> grey -> detections -> tags -> selection, no I/O
- ``service``   the Zenoh node (subscriber, worker, publishers, status, liveliness) and its parts
- ``camera``    what publishes frames when no ZED does: shared memory, replay
- ``cli``       the ``zenoh-perception`` command

The benchmarks, the synthetic scene generator and the demo camera are a second package of
the repository (``bench/``, ``zenoh_perception_bench``) that the service does not ship.
"""

__version__ = "0.1.0"
