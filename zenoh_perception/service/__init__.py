"""The Zenoh side of the service: the node that wires the pipeline to Zenoh, and its parts.

``node`` (subscribers, workers, status, liveliness, the streams served), ``stream`` (one
camera's state and outputs), ``mailbox`` (newest frame wins, per stream, handed out fairly
to the workers), ``stats`` (counters and the rate-limited log gate), ``logs``, ``signals``,
``status`` (the client side of the status queryable) and ``zenoh_args`` (the Zenoh session
flags every command shares).
"""
