"""The benchmarks a user runs on their own data and machine (not tests): they print figures
side by side with OpenCV's default. Run them through ``zenoh-perception bench``.

``zenoh-perception bench`` (:mod:`.generated`) and ``bench --dataset`` (:mod:`.dataset`) are
built from: :mod:`.progress` (the progress bar), :mod:`.scoring` (what a detector got right),
:mod:`.runners` (OpenCV's default, its best setting and the service's detector, side by
side),
:mod:`.framesets` (the generated frames), :mod:`.processes` (services in processes of their
own, the bench's camera), :mod:`.e2e` (lockstep end to end through them and :mod:`.floor`,
the transport floor), :mod:`.throughput`, :mod:`.goals`, :mod:`.report` (the text reports) and
:mod:`.plot`. ``--overhead`` is :mod:`.overhead`, ``--peer ros2`` :mod:`.peer`. The project's
own stress tools (flood, soak, fuzz, stalls) are not in the package: ``tools/`` in the
repository.
"""
