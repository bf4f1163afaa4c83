"""The camera side: what puts frames on ``zed/left/image`` when no ZED does.

``defaults`` holds the key, frame id and rate a camera uses unless told otherwise; ``shm``
publishes from a shared-memory buffer, ``sources`` reads recordings from disk, ``replay``
publishes them, ``demo`` runs a synthetic camera with the service and an echo.
"""
