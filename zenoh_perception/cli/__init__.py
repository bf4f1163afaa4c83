"""The ``zenoh-perception`` command: ``main`` parses, consumer tools ``echo`` and ``status``.

Each subcommand's module is imported only when that subcommand runs.
"""
