"""Marker detection: OpenCV's ArUco detector decides what a marker is and which id it has.

- :mod:`.types`: :class:`~.types.Detection`, the :class:`~.types.Detector` protocol and the
  names of the dictionaries and detectors (no OpenCV import: settings validate with these);
- :mod:`.opencv`: ``cv2.aruco.ArucoDetector`` with OpenCV's default parameters, every frame;
- :mod:`.tracking`: the same detector, run on the whole frame only when it must be and on the
  regions around known tags in between;
- :mod:`.factory`: :func:`~.factory.make_detector`, a detector by name.
"""
