"""The Zenoh side of the service: the node that wires the pipeline to Zenoh, and its parts.

``node`` (the service: its subscriptions, declarations, threads and serve loop, wiring the
rest), ``session`` (opening the session, its message limit, its connect endpoints),
``inputs`` (which input a key is, the stream it names), ``registry`` (the streams served),
``camera_infos``, ``workers`` (workers and watchdog), ``report`` (status document, stats
lines), ``liveliness`` (other services on the same keys), ``stream`` (one camera's state and
outputs), ``mailbox`` (newest frame wins, per stream, handed out fairly to the workers),
``stats`` (counters and the rate-limited log gate), ``logs``, ``signals``, ``status`` (the
client side of the status queryable) and ``zenoh_args`` (the Zenoh session flags every
command shares).
"""
