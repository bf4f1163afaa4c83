"""Bytes to objects and back, for everything on the wire; no Zenoh.

``messages`` registers the ROS 2 types in one rosbags typestore; ``frames`` decodes camera
frames; ``records`` encodes the ``tag`` CDR and the ``perception/tags`` record; ``camera_info``
reads intrinsics from CameraInfo; ``debug_image`` draws and compresses the debug image;
``text`` prints the outputs as one line of text or JSON each.
"""
