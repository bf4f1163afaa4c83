"""The ``zenoh-perception`` command: ``main`` parses and dispatches, ``commands`` holds each
subcommand's flags and handler, ``echo`` and ``status`` are the consumer tools.

Each subcommand's module is imported only when that subcommand runs.
"""
