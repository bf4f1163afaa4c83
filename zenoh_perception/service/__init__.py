"""The Zenoh side of the service: the node that wires the pipeline to Zenoh, and its parts.

``node`` (subscriber, worker, publishers, status, liveliness), ``mailbox`` (newest frame
wins), ``stats`` (counters and the rate-limited log gate), ``logs``, ``signals``, ``status``
(the client side of the status queryable) and ``zenoh_args`` (the Zenoh session flags every
command shares).
"""
