"""Benchmark and stress scripts (not tests): they print figures side by side with a baseline.

Run them through ``zenoh-perception bench`` or ``python -m zenoh_perception.bench.<name>``.

``zenoh-perception bench`` (:mod:`.generated`) and ``bench --dataset`` (:mod:`.dataset`) are
built from: :mod:`.progress` (the progress bar), :mod:`.scoring` (what a detector got right),
:mod:`.runners` (OpenCV's default and the service's detector, side by side),
:mod:`.framesets` (the generated frames), :mod:`.processes` (services in processes of their
own, the bench's camera), :mod:`.e2e` (lockstep end to end through them and :mod:`.floor`,
the transport floor), :mod:`.throughput`, :mod:`.goals`, :mod:`.report` (the text reports) and
:mod:`.plot`. :mod:`.flood`, :mod:`.soak` and :mod:`.fuzz` (its payloads in
:mod:`.fuzz_cases`) load, soak and fuzz the service, driving it with :mod:`.rig`.
"""
