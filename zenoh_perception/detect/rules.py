"""The veto rules: what each measures on a marker OpenCV decided on, and the thresholds
under which it vetoes it. Pure: no Zenoh, no logging.

OpenCV's ``ArucoDetector`` proposes every marker and its id; :class:`Verifier` re-reads each
one from the grey image and may reject it, never add one nor change its id or corners. The
marker's quad is warped once onto a grid of its own cells (border included) plus one ring of
cells outside it (the quiet zone); every grid below is read from that one patch, each cell on
its central half. On the scale from the border's median level (0) to the white cells' (1):

- ``resolution``: a quad whose shortest side holds less than :data:`MIN_PX_PER_CELL` pixel
  per cell across it (the inner cells and the border, e.g. 6 for DICT_4X4) was decoded below
  the image's own resolution (slivers one or two pixels wide on fur or window frames; a true
  tag, however oblique, keeps more than one pixel a cell on the real corpus, and down to
  0.875 on the generator's oblique 10 px tags). Checked before the cells are read;
- ``quiet_zone``: a printed marker sits on a light margin as light as its white cells (the
  same paper). The ring's median must lie in [:data:`QUIET_MIN`, :data:`QUIET_MAX`]: below,
  the "marker" is a dark patch on something dark (a key-cap with a light glyph on a dark
  keyboard, a letter on a book spine); above, its "white" cells are far darker than what
  surrounds it (a dark window or a faint glyph in a light scene). Ring cells outside the image
  are left out: a marker at the image border keeps its chance. Hard light stripes (sun through
  blinds) put some of a true tag's cells and of the paper round it in shadow, so the ring can
  read below QUIET_MIN of the lit white cells; such a ring still passes when its local level
  (``cells._local_quiet``: each ring cell between a border cell beside it and a white cell
  near it, the pair whose light it shares, then the median) is at least :data:`QUIET_LOCAL_MIN`.
  A dark patch on something dark reads as dark locally too (glyphs on book spines at most
  0.40, the real corpus's at most 0.30), while the striped tags it keeps read 0.65-1.0. Above
  QUIET_MAX no local reading helps: a marker in a shadow stripe with the paper round it lit
  reads like a dark window on a light wall (every white cell darker than the ring), so that
  case is still vetoed. A small marker, under :data:`QUIET_SMALL_PX_PER_CELL` pixels a cell,
  passes from :data:`QUIET_LOCAL_MIN_SMALL` locally: a blurred ChArUco board's black squares
  touch its markers' rings at the corners (true board markers at 1.5-1.8 px a cell read 0.30-0.35,
  locally 0.44-0.49), while the darkest surrounds of that size the local level still vetoes
  read at most 0.11 on the real corpus and 0.38 among the generator's look-alikes (text on dark
  ground; up to 0.40 at 3-4 px a cell, where the bound stays 0.5). Nor does the low side veto
  a large marker, :data:`QUIET_WAIVER_PX_PER_CELL` pixels a cell or more, whose cells read as
  its id by :data:`QUIET_WAIVER_BITS` or more against every other id of its dictionary: a
  marker printed to the edge of its sheet, or cut out, on a dark ground (a 5X5 marker on a
  tree's bark: 0.33, locally 0.44, 145 px a cell, 6.9 bits). The dark patches the low side is
  for are smaller: every false id on the real corpus has at most 12 px a cell (those the low
  side vetoes, 7 px and 1.65 bits); the generator draws codes on dark ground as look-alikes,
  clean to the last bit, up to 46 px a cell in its HD1080 set;
- ``border``: a marker's border is dark all round. At most :data:`BORDER_LIGHT_MAX` of its
  border cells may be nearer the white level than the border's;
- ``grid``: the quad read on the grids of the families with more cells (up to 7 inner cells
  a side): a marker's cells are more uniform on its own grid than on a finer one, so when the
  cells' spread (mean standard deviation inside each cell) on its own grid is more than
  :data:`GRID_RATIO_MAX` times the least on a finer grid, the quad is a finer family's marker
  whose cells happen to read as a code of the coarser one (tag36h11 read as DICT_4X4 or
  tag16h5, 6X6 read as DICT_4X4 or 5X5: the confusions the real corpus shows);
- ``strokes``: a printed marker's cells meet edge to edge, so the seam between two cells of
  one colour (and the corner four share) reads as those cells do; a symbol's strokes do not
  follow the cell grid. :func:`stroke_excess` takes, over every such seam (a window half a cell
  wide on it), how far its mean strays from its cells' cores towards the other colour (above
  the lightest dark cell, below the darkest white one), over the contrast; above
  :data:`STROKES_MAX` the marker is a symbol's strokes read as a code: handling pictograms in
  a dark square on cardboard (arrows with thin shafts and slanted heads, an umbrella, a glass
  on a stem, crossed-out boxes), which OpenCV reads as DICT_4X4 ids and no other rule here
  removes (a light surround, a dark edge all round, and whole cells white). Applied from
  :data:`STROKES_MIN_PX_PER_CELL` pixels per cell along the shortest side: with fewer, a true
  tag's blur alone lights its dark seams. At 2 px a cell or more, the generator's true tags of
  every family (10-60 px, blurred, oblique, in shadow, JPEG'd; 28 653) reach 0.21 (99th
  percentile 0.08), the real corpus's true tags 0.32 (a drone's video of a tag whose dark
  cells read grey between darker halos; next 0.27, tag36h11 tags of about 250 px), while the
  pictograms the other rules keep (2 799, 14-34 px) have a median of 0.66 and a 5th
  percentile of 0.39. The bound sits 1.4 times above the real corpus's highest true tag: about
  1 pictogram in 10 stays (a glass or a pair of arrows at 14-20 px, blurred, reads as a clean
  enough code). The corpus's negatives' glyphs on a compass dial read 0.62 and 0.67;
- ``margin``: the inner cells' levels (clipped to [0, 1]) scored against every code of the
  dictionary, in every rotation, as the sum over the cells of the distance to the code's bit:
  a marker's own code scores far better than any other id's, while a glyph whose strokes
  cross the cells scores about as well on another id. The best other id's score minus the
  own code's is the decision's margin, in bits; under :data:`MARGIN_MIN_BITS` the id is a
  coin toss between two codes (OpenCV decides each bit alone and never sees how close it was).
  Each cell's level is read against the light around it (:func:`_local_levels`): between the
  mean of the dark cells next to it (0) and the mean of the white cells within
  :data:`LEVEL_WHITE_REACH` cells (1), dark and white as the code OpenCV read says, the cell
  itself left out. Light is shared by neighbouring cells, so a white cell in a shadow stripe
  reads white beside its shadowed neighbours, where on the whole marker's scale it read as
  dark and made a true tag a close call.
  A blurred or noisy true tag can be such a close call too, so the rule vetoes it only when
  its quiet zone is not as light as a printed marker's (outside :data:`TYPICAL_QUIET`, within
  the wider bounds of ``quiet_zone``): a close call needs the surround of paper. Not applied
  to a dictionary with ids one bit apart (ARUCO_ORIGINAL), where a blurred true tag has no
  margin either.

docs/benchmarks.md gives the distributions of these features on the true and false
detections of the project's real corpus that set the thresholds, and what each rule removes.
:func:`measure` reads every rule's number whatever the thresholds, and :func:`veto_reasons`
gives the veto under other :class:`Thresholds`: what tools/thresholds.py fits the thresholds
with, on some repositories of the corpus, and measures them with on the others.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Final, Protocol

#: The veto reasons, in the order they are checked.
REASONS: Final = ("resolution", "quiet_zone", "border", "grid", "strokes", "margin")
#: Fewest pixels per cell along a quad's shortest side (cells: inner cells and border).
MIN_PX_PER_CELL: Final = 0.5
#: The quiet zone's median level must lie in [QUIET_MIN, QUIET_MAX] (border 0, white cells 1).
QUIET_MIN: Final = 0.35
QUIET_MAX: Final = 1.8
#: Most share of border cells nearer the white level than the border's.
BORDER_LIGHT_MAX: Final = 0.35
#: Most ratio of the cells' spread on the marker's own grid to the least on a finer grid.
GRID_RATIO_MAX: Final = 2.5
#: Least decision margin, bits: how much better the own code explains the cells than any other,
#: for a marker whose quiet zone lies outside TYPICAL_QUIET.
MARGIN_MIN_BITS: Final = 0.5
#: A quiet zone as light as a printed marker's white cells (the true tags' 1st to 99th
#: percentiles are 0.87 and 1.12 on the real corpus).
TYPICAL_QUIET: Final = (0.8, 1.25)
#: The ``strokes`` rule: applied from this many pixels per cell along the quad's shortest side
#: (cells: inner cells and border; fewer, a true tag's blur alone lights the seams between its
#: dark cells), it vetoes a marker whose worst seam between cells of one colour differs from
#: those cells by more than STROKES_MAX of the contrast.
STROKES_MIN_PX_PER_CELL: Final = 2.0
STROKES_MAX: Final = 0.45
#: A quiet zone below QUIET_MIN still passes when its local level (each ring cell against the
#: marker cells near it) is at least this: the marker lit, the paper around it in a shadow.
QUIET_LOCAL_MIN: Final = 0.5
#: ... and, for a marker of fewer than QUIET_SMALL_PX_PER_CELL pixels a cell along its shortest
#: side, at least QUIET_LOCAL_MIN_SMALL (the bound per cell size: docs/benchmarks.md).
QUIET_SMALL_PX_PER_CELL: Final = 2.0
QUIET_LOCAL_MIN_SMALL: Final = 0.42
#: A quiet zone below both still passes for a marker of at least QUIET_WAIVER_PX_PER_CELL
#: pixels a cell along its shortest side whose cells read as its id by at least
#: QUIET_WAIVER_BITS (:func:`decision_margin`, in a dictionary whose codes lie 2 bits apart or
#: more): a large clean code printed without a light margin.
QUIET_WAIVER_PX_PER_CELL: Final = 60.0
QUIET_WAIVER_BITS: Final = 3.0


@dataclass(frozen=True, slots=True)
class Measures:
    """Every number a rule compares with its threshold, for one detection, each read whether or
    not its rule would be consulted (for studying the thresholds: :func:`measure`)."""

    shortest_side_px: float  # the quad's shortest side
    cells_across: int  # inner cells and border a side (marker_size + 2)
    quiet: float  # Reading.quiet
    quiet_local: float  # Reading.quiet_local, read whatever ``quiet`` is
    border_light: float
    grid_ratio: float
    strokes: float  # stroke_excess, whatever the pixels per cell
    margin: float | None  # decision_margin; None where the rule never applies (see check)

    @property
    def px_per_cell(self) -> float:
        """Pixels per cell along the shortest side (what ``resolution`` and ``strokes`` gate
        on)."""
        return self.shortest_side_px / self.cells_across


@dataclass(frozen=True, slots=True)
class Thresholds:
    """The rules' thresholds; the defaults are the module's constants."""

    min_px_per_cell: float = MIN_PX_PER_CELL
    quiet_min: float = QUIET_MIN
    quiet_max: float = QUIET_MAX
    quiet_local_min: float = QUIET_LOCAL_MIN
    quiet_small_px_per_cell: float = QUIET_SMALL_PX_PER_CELL
    quiet_local_min_small: float = QUIET_LOCAL_MIN_SMALL
    quiet_waiver_px_per_cell: float = QUIET_WAIVER_PX_PER_CELL
    quiet_waiver_bits: float = QUIET_WAIVER_BITS
    border_light_max: float = BORDER_LIGHT_MAX
    grid_ratio_max: float = GRID_RATIO_MAX
    strokes_max: float = STROKES_MAX
    strokes_min_px_per_cell: float = STROKES_MIN_PX_PER_CELL
    margin_min_bits: float = MARGIN_MIN_BITS


#: The thresholds the service vetoes with.
DEFAULTS: Final = Thresholds()


class Measured(Protocol):
    """What the rules compare with their thresholds (:class:`Measures`, or read on demand)."""

    @property
    def shortest_side_px(self) -> float: ...
    @property
    def cells_across(self) -> int: ...
    @property
    def quiet(self) -> float: ...
    @property
    def quiet_local(self) -> float: ...
    @property
    def border_light(self) -> float: ...
    @property
    def grid_ratio(self) -> float: ...
    @property
    def strokes(self) -> float: ...
    @property
    def margin(self) -> float | None: ...


def quiet_waived(m: Measured, t: Thresholds) -> bool:
    """Whether the quiet zone's low side spares a detection of ``m`` under ``t``: a large
    marker whose cells read as its id clearly (see :data:`QUIET_WAIVER_BITS`)."""
    if m.shortest_side_px < t.quiet_waiver_px_per_cell * m.cells_across:
        return False
    margin = m.margin
    return margin is not None and margin >= t.quiet_waiver_bits


def quiet_small(m: Measured, t: Thresholds) -> bool:
    """Whether the marker has so few pixels a cell that its quiet zone's local level is
    bounded by ``quiet_local_min_small``."""
    return m.shortest_side_px < t.quiet_small_px_per_cell * m.cells_across


def local_quiet_min(m: Measured, t: Thresholds) -> float:
    """The least local level of the quiet zone a marker of ``m``'s size needs."""
    return t.quiet_local_min_small if quiet_small(m, t) else t.quiet_local_min


def dark_ring(m: Measured, t: Thresholds) -> bool:
    """Whether the quiet zone reads dark on the whole marker's scale and on the local one."""
    return m.quiet < t.quiet_min and m.quiet_local < local_quiet_min(m, t)


def strokes_read(m: Measured, t: Thresholds) -> bool:
    """Whether the marker has pixels enough a cell for the ``strokes`` rule."""
    return m.shortest_side_px >= t.strokes_min_px_per_cell * m.cells_across


def typical_quiet(m: Measured) -> bool:
    """Whether the quiet zone is as light as a printed marker's: a close call on the id
    stands."""
    return TYPICAL_QUIET[0] <= m.quiet <= TYPICAL_QUIET[1]


def vetoes(m: Measured, t: Thresholds) -> Iterator[str]:
    """Every rule of :data:`REASONS` that vetoes a detection of ``m`` under ``t``, in their
    order: the one implementation of the rules. The service takes the first (and so reads a
    measure only when every rule before it kept the detection); tools/thresholds.py takes
    them all, under other thresholds too."""
    if m.shortest_side_px < t.min_px_per_cell * m.cells_across:
        yield "resolution"
    if m.quiet > t.quiet_max or (dark_ring(m, t) and not quiet_waived(m, t)):
        yield "quiet_zone"
    if m.border_light > t.border_light_max:
        yield "border"
    if m.grid_ratio > t.grid_ratio_max:
        yield "grid"
    if strokes_read(m, t) and m.strokes > t.strokes_max:
        yield "strokes"
    if not typical_quiet(m):
        margin = m.margin
        if margin is not None and margin < t.margin_min_bits:
            yield "margin"


def veto_reasons(measures: Measured, thresholds: Thresholds) -> list[str]:
    """Every rule that vetoes a detection of ``measures`` under ``thresholds`` (:func:`vetoes`):
    :meth:`Verifier.check` with other thresholds (its reason is the first, under
    :data:`DEFAULTS`)."""
    return list(vetoes(measures, thresholds))
