"""What a detection means: centre, closeness and pose per tag, and the one tag a frame reports.

Pure geometry on corner coordinates: no pixels, no wire format, no Zenoh.
"""
