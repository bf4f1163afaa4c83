"""The optimised :mod:`zenoh_perception.detect.refine` against the implementation it replaced
(``tests/reference_refine.py``): same corners (1e-6 px), fits (1e-6 relative), verdicts and
bit readings, on candidates from generated scenes and on drawn perturbations of them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests import reference_refine as reference
from zenoh_perception.detect import refine
from zenoh_perception.detection import aruco_dictionary
from zenoh_perception.scene import CameraModel, Effects, SceneGenerator

Gray = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float64]
Request = tuple[Quad, int, tuple[float, float] | None]
AnyRefined = refine.Refined | reference.Refined
AnyFit = refine.FitResult | reference.FitResult

CORNER_TOLERANCE_PX = 1e-6
RELATIVE = 1e-6
ABSOLUTE = 1e-9
CELLS = 6  # DICT_4X4_50: 4 bits and the border
SCAN = (5, 0.3)  # iterations and tolerance (px) the detector's scan asks for
FOLLOW = (2, 0.4)  # ... and its tracking


@dataclass(frozen=True)
class Candidates:
    """One generated frame and quads to refine and fit on it, each with an id to try."""

    gray: Gray
    quads: list[tuple[Quad, int]]  # perturbed truths, look-alikes, OpenCV's candidates
    truths: list[tuple[Quad, int]]  # exact corners of the visible markers


@cache
def _frames() -> tuple[Candidates, ...]:
    dictionary = aruco_dictionary("DICT_4X4_50")
    scan = cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())
    rng = np.random.default_rng(17)
    frames = []
    for seed in (21, 22, 23):
        generator = SceneGenerator(CameraModel.named("VGA"), seed=seed, effects=Effects.realistic())
        for _ in range(2):
            scene = generator.random_scene(4, 2)
            gray = np.ascontiguousarray(scene.gray(), dtype=np.uint8)
            truths = [(m.corners.copy(), m.tag_id) for m in scene.markers if m.visible]
            quads = [(c + rng.normal(0.0, 0.6, (4, 2)), i) for c, i in truths]
            quads += [
                (d.corners + rng.normal(0.0, 0.3, (4, 2)), d.mimic_id or 0)
                for d in scene.distractors
                if d.visible
            ]
            corners, ids, rejected = scan.detectMarkers(gray)
            if ids is not None:
                quads += [
                    (np.asarray(c, np.float64).reshape(4, 2), int(i))
                    for c, i in zip(corners, ids.ravel(), strict=True)
                ]
            quads += [
                (np.asarray(c, np.float64).reshape(4, 2), int(rng.integers(50)))
                for c in rejected[:6]
            ]
            frames.append(Candidates(gray, quads, truths))
    return tuple(frames)


@cache
def _models() -> tuple[refine.MarkerModel, reference.MarkerModel]:
    """One model of each implementation, shared: their caches never change a result."""
    dictionary = aruco_dictionary("DICT_4X4_50")
    return refine.MarkerModel(dictionary), reference.MarkerModel(dictionary)


def _reference_fits(
    gray: Gray,
    requests: list[Request],
    model: reference.MarkerModel,
) -> list[reference.FitResult]:
    """The reference's fits, 16 at a time: it samples a batch as one row of an image, which
    OpenCV refuses from 32 markers on (32 x 1024 samples, more than SHRT_MAX)."""
    return [
        f
        for k in range(0, len(requests), 16)
        for f in reference.fit_many(gray, requests[k : k + 16], model)
    ]


def _close(a: float, b: float) -> bool:
    return a == b or math.isclose(a, b, rel_tol=RELATIVE, abs_tol=ABSOLUTE)


def _assert_same_refined(new: AnyRefined | None, old: AnyRefined | None) -> None:
    assert (new is None) == (old is None)
    if new is None or old is None:
        return
    assert new.corners.shape == (4, 2)
    assert new.corners.dtype == np.float64
    np.testing.assert_allclose(new.corners, old.corners, rtol=0, atol=CORNER_TOLERANCE_PX)
    for name in ("blur_x_px", "blur_y_px", "profile_px"):
        assert _close(getattr(new, name), getattr(old, name)), name
    assert new.blur_reliable == old.blur_reliable


def _assert_same_fit(new: AnyFit, old: AnyFit) -> None:
    for name in ("score", "sigma_px", "contrast", "cell_px", "noise"):
        assert _close(getattr(new, name), getattr(old, name)), (name, new, old)
    accept_new = new.score <= refine.acceptance_threshold(new.cell_px, new.noise)
    accept_old = old.score <= reference.acceptance_threshold(old.cell_px, old.noise)
    assert accept_new == accept_old


def _requests(frame: Candidates, refined: list[reference.Refined | None]) -> list[Request]:
    """Fit requests as the detector makes them, plus raw corners with and without a blur."""
    out: list[Request] = []
    for (quad, tag_id), r in zip(frame.quads, refined, strict=True):
        if r is not None:
            blur = (r.blur_x_px, r.blur_y_px) if r.blur_reliable else None
            out.append((r.corners, tag_id, blur))
            out.append((r.corners, tag_id, (r.blur_x_px, r.blur_y_px)))
        out.append((quad, tag_id, None))
    return out


# ------------------------------------------------------------------ generated scenes


@pytest.mark.parametrize("passes", [SCAN, FOLLOW, (5, 0.05)], ids=["scan", "follow", "many-passes"])
def test_refine_many_matches_the_reference_on_scene_candidates(passes: tuple[int, float]) -> None:
    refined = 0
    for frame in _frames():
        quads = [q for q, _ in frame.quads]
        new = refine.refine_many(frame.gray, quads, CELLS, *passes)
        old = reference.refine_many(frame.gray, quads, CELLS, *passes)
        assert len(new) == len(old) == len(quads)
        for n, o in zip(new, old, strict=True):
            _assert_same_refined(n, o)
        refined += sum(r is not None for r in new)
        # one at a time, as the detector follows a lost track
        for quad in quads[:3]:
            _assert_same_refined(
                refine.refine_corners(frame.gray, quad, CELLS, *passes),
                reference.refine_corners(frame.gray, quad, CELLS, *passes),
            )
    assert refined >= 20  # the comparison is not between two Nones


def test_fit_many_matches_the_reference_on_scene_candidates() -> None:
    new_model, old_model = _models()
    accepted = rejected = 0
    for frame in _frames():
        refined = reference.refine_many(frame.gray, [q for q, _ in frame.quads], CELLS, *SCAN)
        requests = _requests(frame, refined)
        for _ in range(2):  # models computed, then cached
            new = refine.fit_many(frame.gray, requests, new_model)
            old = _reference_fits(frame.gray, requests, old_model)
            assert len(new) == len(old) == len(requests)
            for n, o in zip(new, old, strict=True):
                _assert_same_fit(n, o)
        accepted += sum(r.score <= refine.acceptance_threshold(r.cell_px, r.noise) for r in new)
        rejected += sum(r.score > refine.acceptance_threshold(r.cell_px, r.noise) for r in new)
        for corners, tag_id, blur in requests[:4]:
            _assert_same_fit(
                refine.fit_marker(frame.gray, corners, tag_id, new_model, blur),
                reference.fit_marker(frame.gray, corners, tag_id, old_model, blur),
            )
    assert accepted >= 10
    assert rejected >= 10


def test_fits_do_not_depend_on_the_cache_or_the_batch() -> None:
    """A fresh model and one request at a time give the batch's results."""
    frame = _frames()[0]
    refined = reference.refine_many(frame.gray, [q for q, _ in frame.quads], CELLS, *SCAN)
    requests = _requests(frame, refined)
    dictionary = aruco_dictionary("DICT_4X4_50")
    batch = refine.fit_many(frame.gray, requests, refine.MarkerModel(dictionary))
    alone = [refine.fit_many(frame.gray, [r], refine.MarkerModel(dictionary))[0] for r in requests]
    for a, b in zip(batch, alone, strict=True):
        _assert_same_fit(a, b)


def test_bits_match_matches_the_reference_on_scene_candidates() -> None:
    new_model, old_model = _models()
    matches = 0
    for frame in _frames():
        requests = [(q, i) for q, i in frame.truths]
        requests += [(q, (i + 1 + k) % 50) for k, (q, i) in enumerate(frame.truths)]
        requests += frame.quads
        for max_errors in (0, 1, 3):
            new = refine.bits_match(frame.gray, requests, new_model, max_errors)
            assert new == reference.bits_match(frame.gray, requests, old_model, max_errors)
            matches += sum(new)
    assert matches >= 10


def test_the_models_match_the_reference() -> None:
    new_model, old_model = _models()
    for tag_id, cell_x, cell_y, blur in [
        (3, 5.0, 6.1, (1.2, 0.9)),
        (17, 2.5, 2.2, None),
        (49, 40.0, 33.0, (0.4, 2.5)),
        (0, 0.3, 0.2, (0.05, 30.0)),  # clamped sizes and blurs
        (5, 500.0, 600.0, None),  # blur widths under 1e-3 cell: clamped
        (6, 450.0, 30.0, (0.2, 0.3)),
    ]:
        new = new_model.centred(tag_id, cell_x, cell_y, blur)
        old = old_model.centred(tag_id, cell_x, cell_y, blur)
        np.testing.assert_allclose(new.centred, old.centred, rtol=0, atol=1e-12)
        assert new.sigmas == pytest.approx(old.sigmas, rel=1e-15)
        for name in ("norms", "code_sums", "code_norms", "flat_sums", "flat_norms"):
            assert getattr(new, name) == pytest.approx(getattr(old, name), rel=1e-9, abs=1e-9)
    sigmas = np.array([0.01, 0.2, 0.7, 3.0])
    np.testing.assert_allclose(
        new_model.blurred(7, sigmas, sigmas[::-1]),
        old_model.blurred(7, sigmas, sigmas[::-1]),
        rtol=0,
        atol=1e-12,
    )
    np.testing.assert_array_equal(new_model.darkness(7), old_model.darkness(7))


def test_blur_buckets_by_integer_arithmetic_are_the_logarithms() -> None:
    """refine's models bucket their blur widths with integers (see _FACTOR_BUCKETS): the
    same buckets as the logarithms the reference takes, over every size and blur bucket."""
    step = reference.MarkerModel._BUCKET

    def bucket(sigma_px: float, size: int) -> int:  # as the reference computes it
        return round(math.log(max(sigma_px / math.exp(size * step), 1e-3)) / step)

    lowest = refine._LOWEST_BUCKET
    offsets = refine._FACTOR_BUCKETS
    for size in range(-24, 200):  # cells of 0.5 px and more
        for blur in range(-78, 120):  # blurs of 0.1 px and more
            width = math.exp(blur * step)
            for factor, offset in zip(refine.FIT_BLUR_FACTORS, offsets, strict=True):
                assert bucket(width * factor, size) == max(blur - size + offset, lowest)
        for sigma, offset in zip(refine.FIT_SIGMAS_PX, refine._SIGMA_BUCKETS, strict=True):
            assert bucket(sigma, size) == max(offset - size, lowest)


# ------------------------------------------------------------------ edge cases


def test_empty_batches_and_degenerate_quads() -> None:
    new_model, old_model = _models()
    gray = _frames()[0].gray
    assert refine.refine_many(gray, [], CELLS) == []
    assert reference.refine_many(gray, [], CELLS) == []
    assert refine.fit_many(gray, [], new_model) == []
    assert refine.bits_match(gray, [], new_model) == []
    tiny = np.array([[10.0, 10.0], [12.0, 10.0], [12.0, 12.0], [10.0, 12.0]])
    point = np.full((4, 2), 50.0)
    outside = np.array([[-40.0, -30.0], [20.0, -30.0], [20.0, 30.0], [-40.0, 30.0]])
    flat = np.full_like(gray, 128)
    for image in (gray, flat):
        quads = [tiny, point, outside, _frames()[0].truths[0][0]]
        for n, o in zip(
            refine.refine_many(image, quads, CELLS, *SCAN),
            reference.refine_many(image, quads, CELLS, *SCAN),
            strict=True,
        ):
            _assert_same_refined(n, o)
        requests = [(q, 5, b) for q in quads for b in (None, (1.0, 1.0), (0.0, 2.0))]
        for n2, o2 in zip(
            refine.fit_many(image, requests, new_model),
            reference.fit_many(image, requests, old_model),
            strict=True,
        ):
            _assert_same_fit(n2, o2)
        bits = [(q, 5) for q in quads]
        assert refine.bits_match(image, bits, new_model) == reference.bits_match(
            image, bits, old_model
        )


# ------------------------------------------------------------------ drawn perturbations


@dataclass(frozen=True)
class Perturbation:
    """A marker of one of the frames, moved, scaled, read as some id, with some blur."""

    frame: int
    marker: int
    offsets: tuple[float, ...]  # 8: x, y of each corner
    scale: float
    tag_id: int | None  # None: its own id
    blur: tuple[float, float] | None


_perturbations = st.builds(
    Perturbation,
    frame=st.integers(0, 5),
    marker=st.integers(0, 3),
    offsets=st.tuples(*[st.floats(-2.0, 2.0)] * 8),
    scale=st.floats(0.9, 1.1),
    tag_id=st.none() | st.integers(0, 49),
    blur=st.none() | st.tuples(st.floats(0.05, 6.0), st.floats(0.05, 6.0)),
)


@given(_perturbations)
def test_drawn_perturbations_of_markers_match_the_reference(drawn: Perturbation) -> None:
    candidates = _frames()[drawn.frame]
    truth, true_id = candidates.truths[drawn.marker % len(candidates.truths)]
    centre = truth.mean(axis=0)
    quad = centre + (truth - centre) * drawn.scale + np.reshape(drawn.offsets, (4, 2))
    tag = true_id if drawn.tag_id is None else drawn.tag_id
    new_model, old_model = _models()
    gray = candidates.gray
    for passes in (SCAN, FOLLOW):
        _assert_same_refined(
            refine.refine_corners(gray, quad, CELLS, *passes),
            reference.refine_corners(gray, quad, CELLS, *passes),
        )
    _assert_same_fit(
        refine.fit_marker(gray, quad, tag, new_model, drawn.blur),
        reference.fit_marker(gray, quad, tag, old_model, drawn.blur),
    )
    for max_errors in (0, 1):
        assert refine.bits_match(gray, [(quad, tag)], new_model, max_errors) == (
            reference.bits_match(gray, [(quad, tag)], old_model, max_errors)
        )


@given(
    frame=st.integers(0, 5),
    picks=st.lists(st.integers(0, 40), min_size=1, max_size=8),
    jitter=st.floats(0.0, 1.5),
    seed=st.integers(0, 2**16),
)
def test_drawn_batches_of_candidates_match_the_reference(
    frame: int, picks: list[int], jitter: float, seed: int
) -> None:
    """Batches mixing markers, look-alikes and OpenCV's candidates, moved a little: each
    marker's result does not depend on the others in its batch."""
    candidates = _frames()[frame]
    rng = np.random.default_rng(seed)
    chosen = [candidates.quads[p % len(candidates.quads)] for p in picks]
    quads = [q + rng.normal(0.0, jitter, (4, 2)) for q, _ in chosen]
    gray = candidates.gray
    new = refine.refine_many(gray, quads, CELLS, *SCAN)
    old = reference.refine_many(gray, quads, CELLS, *SCAN)
    for n, o in zip(new, old, strict=True):
        _assert_same_refined(n, o)
    new_model, old_model = _models()
    requests = [
        (o.corners if o is not None else q, i, (o.blur_x_px, o.blur_y_px) if o else None)
        for q, (_, i), o in zip(quads, chosen, old, strict=True)
    ]
    for n2, o2 in zip(
        refine.fit_many(gray, requests, new_model),
        _reference_fits(gray, requests, old_model),
        strict=True,
    ):
        _assert_same_fit(n2, o2)


def test_batches_too_wide_for_the_reference_are_sampled_by_rows() -> None:
    """The reference fails on 32 fits, 61 quads or 911 bit readings at once (one row of
    samples wider than OpenCV takes); refine samples such batches by rows, same results."""
    frame = _frames()[1]
    new_model, old_model = _models()
    quads = [q for q, _ in frame.quads] * (70 // len(frame.quads) + 1)
    new = refine.refine_many(frame.gray, quads, CELLS, *SCAN)
    assert len(new) >= 61
    for k in range(0, len(quads), 20):
        old = reference.refine_many(frame.gray, quads[k : k + 20], CELLS, *SCAN)
        for n, o in zip(new[k : k + 20], old, strict=True):
            _assert_same_refined(n, o)
    once: list[Request] = [(q, i, None) for q, i in frame.quads]
    requests = once * (40 // len(once) + 1)
    assert len(requests) >= 32
    with pytest.raises(cv2.error):
        reference.fit_many(frame.gray, requests, old_model)
    for n2, o2 in zip(
        refine.fit_many(frame.gray, requests, new_model),
        _reference_fits(frame.gray, requests, old_model),
        strict=True,
    ):
        _assert_same_fit(n2, o2)
    bits = frame.quads * (1000 // len(frame.quads) + 1)
    expected = [
        b
        for k in range(0, len(bits), 500)
        for b in reference.bits_match(frame.gray, bits[k : k + 500], old_model)
    ]
    assert refine.bits_match(frame.gray, bits, new_model) == expected
