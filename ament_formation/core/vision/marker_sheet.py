"""Printable marker sheets and ChArUco calibration boards at a stated physical size.

A sheet is laid out in millimetres on pages (origin at a page's top-left corner, x right, y down)
as black rectangles and text lines, so that the same layout is written exactly as vector PDF
(:func:`pdf_bytes`: every edge where the layout puts it) and rasterised at any resolution
(:func:`rasterize`: every edge rounded to the nearest pixel, ±0.5 px). Each page states what is
on it and a 100 mm bar to check the print scale with a ruler; each marker and board is labelled
with its id(s), dictionary and size.

- Markers: cells of the dictionary's code with a 1-cell black border, side ``marker_size_m``,
  at least one code cell of white between markers (the quiet zone the detector needs).
- Board: OpenCV's own picture of the ChArUco board (so the pattern is the one the detector
  expects), converted into rectangles: edges within ``square / _BOARD_PX_PER_SQUARE`` of their
  place (0.1 mm for a 40 mm square).

:class:`PlacedItem` records where each marker and board sits on its page, which tests (and a
user) can check against the printed or photographed sheet.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import re

import cv2
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import aruco_compat
from ament_formation.core.vision.calibration import CharucoSpec
from ament_formation.core.vision.robot_marker import aruco_dictionary, dictionary_size

MM_PER_INCH = 25.4
PT_PER_MM = 72.0 / MM_PER_INCH
PAGES_MM = {
    'a5': (148.0, 210.0),
    'a4': (210.0, 297.0),
    'a3': (297.0, 420.0),
    'a2': (420.0, 594.0),
    'letter': (215.9, 279.4),
    'legal': (215.9, 355.6),
    'tabloid': (279.4, 431.8),
}
SCALE_BAR_MM = 100.0
_HEADER_MM = 14.0  # header text + scale bar
_TEXT_MM = 3.0  # label text height
_GAP_MM = 8.0  # smallest space between two items
_BOARD_PX_PER_SQUARE = 400


@dataclass(frozen=True)
class Rect:
    """A black rectangle on a page [mm] (top-left corner, width, height)."""

    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float


@dataclass(frozen=True)
class Label:
    """A line of text on a page: baseline-left corner (x_mm, y_mm), cap height [mm]."""

    x_mm: float
    y_mm: float
    height_mm: float
    text: str


@dataclass(frozen=True)
class PlacedItem:
    """What sits where: a marker (``ident`` = its id), the board (``ident`` = -1) or the scale bar
    (-2); (x_mm, y_mm) its top-left corner on page ``page``, (w_mm, h_mm) its size.
    """

    kind: str  # 'marker' | 'board' | 'scale_bar'
    ident: int
    page: int
    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float


@dataclass(frozen=True)
class Page:
    """One page: size (width, height) [mm], its rectangles and text lines."""

    size_mm: tuple[float, float]
    rects: tuple[Rect, ...]
    labels: tuple[Label, ...]


@dataclass(frozen=True)
class Sheet:
    """The laid-out pages and where every item went."""

    pages: tuple[Page, ...]
    items: tuple[PlacedItem, ...]
    description: str  # one line: what the file holds and at what size


def parse_ids(text: str) -> tuple[int, ...]:
    """``"0-9"``, ``"0,1,5"`` or ``"0-3,7"`` → sorted distinct ids; ConfigError naming --ids."""
    ids: set[int] = set()
    for part in str(text).replace(' ', '').split(','):
        m = re.fullmatch(r'(\d+)(?:-(\d+))?', part)
        if not m:
            raise ConfigError(f'expected ids like 0-9 or 0,1,5 (got {text!r})', '--ids')
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) else lo
        if hi < lo or hi - lo > 10000:
            raise ConfigError(f'bad range {part!r}', '--ids')
        ids.update(range(lo, hi + 1))
    return tuple(sorted(ids))


def parse_page(text: str) -> tuple[float, float]:
    """A page name (a4, letter, ...) or ``WxH`` in mm (e.g. 300x400) → (width, height) [mm]."""
    key = str(text).strip().lower()
    if key in PAGES_MM:
        return PAGES_MM[key]
    m = re.fullmatch(r'(\d+(?:\.\d+)?)x(\d+(?:\.\d+)?)', key)
    if not m:
        raise ConfigError(
            f'expected {", ".join(PAGES_MM)} or WxH in mm (got {text!r})', '--page'
        )
    w, h = float(m.group(1)), float(m.group(2))
    if not (50.0 <= w <= 5000.0 and 50.0 <= h <= 5000.0):
        raise ConfigError(f'{w:g} x {h:g} mm: each side must be in [50, 5000] mm', '--page')
    return (w, h)


@dataclass(frozen=True)
class SheetSpec:
    """What to print: markers ``marker_ids`` of ``dictionary`` at ``marker_size_m``, and/or a
    ChArUco ``board``, on pages of ``page_mm`` (width, height) with ``margin_mm`` margins.
    """

    marker_ids: tuple[int, ...] = ()
    marker_size_m: float = 0.12
    dictionary: str = 'DICT_4X4_50'
    board: CharucoSpec | None = None
    page_mm: tuple[float, float] = PAGES_MM['a4']
    margin_mm: float = 10.0

    def __post_init__(self) -> None:
        if not self.marker_ids and self.board is None:
            raise ConfigError('nothing to print: give marker ids and/or a board', '--ids')
        n_ids = dictionary_size(self.dictionary)
        bad = [i for i in self.marker_ids if not 0 <= i < n_ids]
        if bad:
            raise ConfigError(
                f'marker id {bad[0]} not in {self.dictionary} (0..{n_ids - 1})', '--ids'
            )
        s = self.marker_size_m
        if not (isinstance(s, (int, float)) and math.isfinite(s) and 0.01 <= s <= 2.0):
            raise ConfigError(f'must be in [0.01, 2] m (got {s!r})', '--marker-size-m')
        if not (math.isfinite(self.margin_mm) and 0.0 <= self.margin_mm <= 50.0):
            raise ConfigError(f'must be in [0, 50] mm (got {self.margin_mm!r})', '--margin-mm')

    @property
    def cell_mm(self) -> float:
        """One code cell of a marker [mm]."""
        bits = int(aruco_dictionary(self.dictionary).markerSize)
        return self.marker_size_m * 1000.0 / (bits + 2)


# ------------------------------------------------------------------------------- layout
def _cells_to_rects(black: np.ndarray, x0: float, y0: float, cell_w: float, cell_h: float):
    """Rectangles covering the True cells of ``black`` (R, C): horizontal runs of a row, merged
    with the same runs of the rows below.
    """
    rows: list[list[tuple[int, int]]] = []
    for row in black:
        padded = np.concatenate([[False], row, [False]]).astype(np.int8)
        d = np.diff(padded)
        rows.append(list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))))
    rects = []
    r = 0
    while r < len(rows):
        r_end = r + 1
        while r_end < len(rows) and rows[r_end] == rows[r]:
            r_end += 1
        for c0, c1 in rows[r]:
            rects.append(
                Rect(x0 + c0 * cell_w, y0 + r * cell_h, (c1 - c0) * cell_w, (r_end - r) * cell_h)
            )
        r = r_end
    return rects


def marker_rects(spec: SheetSpec, marker_id: int, x_mm: float, y_mm: float) -> list[Rect]:
    """Black rectangles of marker ``marker_id`` with its top-left corner at (x_mm, y_mm)."""
    cells = ~aruco_compat.marker_cells(aruco_dictionary(spec.dictionary), marker_id)
    c = spec.cell_mm
    return _cells_to_rects(cells, x_mm, y_mm, c, c)


def board_rects(board: CharucoSpec, x_mm: float, y_mm: float) -> list[Rect]:
    """Black rectangles of the ChArUco ``board`` with its top-left corner at (x_mm, y_mm)."""
    p = _BOARD_PX_PER_SQUARE
    img = board.image(p)  # OpenCV's own picture: exactly squares_x * p by squares_y * p
    px_mm = board.square_m * 1000.0 / p
    return _cells_to_rects(img < 128, x_mm, y_mm, px_mm, px_mm)


def _header(page_w: float, margin: float, what: str) -> tuple[list[Rect], list[Label], float]:
    usable = page_w - 2 * margin
    bar = SCALE_BAR_MM if usable >= SCALE_BAR_MM + 10 else 50.0
    labels = [
        Label(margin, margin + 4.0, _TEXT_MM, what),
        Label(
            margin,
            margin + 9.0,
            _TEXT_MM,
            f'Print at 100 % (no "fit to page"). This bar measures {bar:.1f} mm:',
        ),
    ]
    rects = [Rect(margin, margin + 10.5, bar, 2.0)]
    return rects, labels, bar


def _marker_pages(spec: SheetSpec, page_w: float, page_h: float):
    """Pages of markers in a grid: [(rects, labels, items-without-page)]."""
    m, s_mm = spec.margin_mm, spec.marker_size_m * 1000.0
    gap = max(_GAP_MM, spec.cell_mm)  # one code cell of white between markers at least
    label_gap = max(2.0, spec.cell_mm)
    item_h = s_mm + label_gap + _TEXT_MM
    top = m + _HEADER_MM + gap
    cols = int((page_w - 2 * m + gap) // (s_mm + gap))
    rows = int((page_h - m - top + gap) // (item_h + gap))
    if cols < 1 or rows < 1:
        raise ConfigError(
            f'a {s_mm:.1f} mm marker does not fit a {page_w:g} x {page_h:g} mm page with '
            f'{m:g} mm margins; use a larger --page or a smaller --marker-size-m',
            '--marker-size-m',
        )
    per_page = cols * rows
    pages = []
    ids = list(spec.marker_ids)
    for start in range(0, len(ids), per_page):
        chunk = ids[start: start + per_page]
        what = (
            f'ArUco {spec.dictionary} markers, side {s_mm:.1f} mm (black square); '
            f'ids {chunk[0]}-{chunk[-1]}'
        )
        rects, labels, bar = _header(page_w, m, what)
        items = [PlacedItem('scale_bar', -2, 0, m, m + 10.5, bar, 2.0)]
        for k, mid in enumerate(chunk):
            x = m + (k % cols) * (s_mm + gap)
            y = top + (k // cols) * (item_h + gap)
            rects += marker_rects(spec, mid, x, y)
            labels.append(
                Label(x, y + s_mm + label_gap + _TEXT_MM, _TEXT_MM, f'id {mid}  {s_mm:.1f} mm')
            )
            items.append(PlacedItem('marker', mid, 0, x, y, s_mm, s_mm))
        pages.append(((page_w, page_h), rects, labels, items))
    return pages


def _board_page(spec: SheetSpec, page_w: float, page_h: float):
    """The board's page (landscape when it fits only that way)."""
    b, m = spec.board, spec.margin_mm
    bw, bh = (v * 1000.0 for v in b.size_m)
    for w, h in ((page_w, page_h), (page_h, page_w)):
        top = m + _HEADER_MM + _GAP_MM
        if bw <= w - 2 * m and bh <= h - m - top:
            what = (
                f'ChArUco board {b.squares_x}x{b.squares_y} squares of {b.square_m * 1e3:.1f} mm, '
                f'markers {b.marker_m * 1e3:.1f} mm, {b.dictionary}'
            )
            rects, labels, bar = _header(w, m, what)
            labels.append(
                Label(
                    m,
                    top + bh + 6.0 + _TEXT_MM,
                    _TEXT_MM,
                    f'formation calibrate intrinsics IMAGES --board {b.squares_x}x{b.squares_y},'
                    f'{b.square_m:g},{b.marker_m:g},{b.dictionary}',
                )
            )
            rects += board_rects(b, m, top)
            items = [
                PlacedItem('scale_bar', -2, 0, m, m + 10.5, bar, 2.0),
                PlacedItem('board', -1, 0, m, top, bw, bh),
            ]
            return ((w, h), rects, labels, items)
    top = m + _HEADER_MM + _GAP_MM
    fit_mm = max(
        min((w - 2 * m) / b.squares_x, (h - m - top) / b.squares_y)
        for w, h in ((page_w, page_h), (page_h, page_w))
    )
    raise ConfigError(
        f'the {bw:.0f} x {bh:.0f} mm board does not fit a {page_w:g} x {page_h:g} mm page '
        f'with {m:g} mm margins (either way round); use a larger --page, or squares of at most '
        f'{math.floor(fit_mm):.0f} mm for {b.squares_x}x{b.squares_y} squares',
        '--board',
    )


def layout(spec: SheetSpec) -> Sheet:
    """Lay ``spec`` out: marker pages first, then the board's page."""
    pw, ph = spec.page_mm
    raw = _marker_pages(spec, pw, ph) if spec.marker_ids else []
    if spec.board is not None:
        raw.append(_board_page(spec, pw, ph))
    pages, items = [], []
    for i, (size, rects, labels, its) in enumerate(raw):
        pages.append(Page(size, tuple(rects), tuple(labels)))
        items += [PlacedItem(t.kind, t.ident, i, t.x_mm, t.y_mm, t.w_mm, t.h_mm) for t in its]
    parts = []
    if spec.marker_ids:
        parts.append(
            f'ArUco {spec.dictionary} markers {_ids_text(spec.marker_ids)} of '
            f'{spec.marker_size_m * 1e3:.1f} mm'
        )
    if spec.board is not None:
        b = spec.board
        parts.append(
            f'ChArUco {b.squares_x}x{b.squares_y} board, squares {b.square_m * 1e3:.1f} mm, '
            f'markers {b.marker_m * 1e3:.1f} mm, {b.dictionary}'
        )
    desc = '; '.join(parts) + f'; {len(pages)} page(s) of {pw:g} x {ph:g} mm, print at 100 %'
    return Sheet(tuple(pages), tuple(items), desc)


def _ids_text(ids: tuple[int, ...]) -> str:
    runs, start = [], ids[0]
    for a, b in zip(ids, ids[1:] + (None,)):
        if b != a + 1:
            runs.append(f'{start}' if start == a else f'{start}-{a}')
            start = b
    return ','.join(runs)


# ------------------------------------------------------------------------------- output
def page_size_px(page: Page, dpi: float) -> tuple[int, int]:
    """(width, height) [px] of ``page`` at ``dpi``."""
    return (
        int(round(page.size_mm[0] * dpi / MM_PER_INCH)),
        int(round(page.size_mm[1] * dpi / MM_PER_INCH)),
    )


def rasterize(page: Page, dpi: float) -> np.ndarray:
    """(H, W) uint8 picture of ``page`` at ``dpi`` (white 255, black 0); each edge of each
    rectangle is at its place rounded to the nearest pixel.
    """
    if not (math.isfinite(dpi) and 72.0 <= dpi <= 2400.0):
        raise ConfigError(f'must be in [72, 2400] (got {dpi!r})', '--dpi')
    w, h = page_size_px(page, dpi)
    img = np.full((h, w), 255, np.uint8)
    k = dpi / MM_PER_INCH
    for r in page.rects:
        x0, x1 = int(round(r.x_mm * k)), int(round((r.x_mm + r.w_mm) * k))
        y0, y1 = int(round(r.y_mm * k)), int(round((r.y_mm + r.h_mm) * k))
        img[max(y0, 0): max(y1, 0), max(x0, 0): max(x1, 0)] = 0
    for lab in page.labels:
        scale = lab.height_mm * k / 22.0  # FONT_HERSHEY_SIMPLEX: cap height 22 px at scale 1
        thick = max(1, int(round(scale * 2)))
        cv2.putText(
            img,
            lab.text,
            (int(round(lab.x_mm * k)), int(round(lab.y_mm * k))),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            0,
            thick,
            cv2.LINE_AA,
        )
    return img


def _pdf_text(text: str) -> str:
    safe = text.encode('latin-1', 'replace').decode('latin-1')
    return safe.replace('\\', '\\\\').replace('(', '\\(').replace(')', '\\)')


def _page_stream(page: Page) -> bytes:
    h_pt = page.size_mm[1] * PT_PER_MM
    ops = ['0 g']
    for r in page.rects:
        ops.append(
            f'{r.x_mm * PT_PER_MM:.4f} {h_pt - (r.y_mm + r.h_mm) * PT_PER_MM:.4f} '
            f'{r.w_mm * PT_PER_MM:.4f} {r.h_mm * PT_PER_MM:.4f} re'
        )
    ops.append('f')
    for lab in page.labels:
        size_pt = lab.height_mm * PT_PER_MM / 0.72  # Helvetica: cap height 0.72 em
        ops.append(
            f'BT /F1 {size_pt:.3f} Tf {lab.x_mm * PT_PER_MM:.4f} '
            f'{h_pt - lab.y_mm * PT_PER_MM:.4f} Td ({_pdf_text(lab.text)}) Tj ET'
        )
    return '\n'.join(ops).encode('latin-1')


def pdf_bytes(sheet: Sheet, title: str = 'ament_formation markers') -> bytes:
    """A PDF of ``sheet``: one page per page, vector rectangles at their exact places, Helvetica
    text, page sizes in points (1/72 in); the viewer is asked not to scale when printing.
    """
    objs: list[bytes] = []

    def add(body: bytes) -> int:
        objs.append(body)
        return len(objs)

    catalog = add(b'')  # filled below
    pages_obj = add(b'')
    font = add(b'<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>')
    kids = []
    for page in sheet.pages:
        stream = _page_stream(page)
        contents = add(
            b'<< /Length %d >>\nstream\n' % len(stream) + stream + b'\nendstream'
        )
        w_pt, h_pt = (v * PT_PER_MM for v in page.size_mm)
        kids.append(
            add(
                (
                    f'<< /Type /Page /Parent {pages_obj} 0 R /MediaBox [0 0 {w_pt:.4f} '
                    f'{h_pt:.4f}] /Contents {contents} 0 R /Resources << /Font << /F1 {font} 0 R'
                    ' >> >> >>'
                ).encode('latin-1')
            )
        )
    info = add(
        (
            f'<< /Title ({_pdf_text(title)}) /Subject ({_pdf_text(sheet.description)}) '
            '/Creator (ament_formation: formation markers) >>'
        ).encode('latin-1')
    )
    objs[catalog - 1] = (
        f'<< /Type /Catalog /Pages {pages_obj} 0 R '
        '/ViewerPreferences << /PrintScaling /None >> >>'
    ).encode('latin-1')
    objs[pages_obj - 1] = (
        f'<< /Type /Pages /Kids [{" ".join(f"{k} 0 R" for k in kids)}] /Count {len(kids)} >>'
    ).encode('latin-1')
    out = bytearray(b'%PDF-1.6\n%\xe2\xe3\xcf\xd3\n')
    offsets = []
    for i, body in enumerate(objs, start=1):
        offsets.append(len(out))
        out += b'%d 0 obj\n' % i + body + b'\nendobj\n'
    xref = len(out)
    out += b'xref\n0 %d\n0000000000 65535 f \n' % (len(objs) + 1)
    for off in offsets:
        out += b'%010d 00000 n \n' % off
    out += (
        b'trailer\n<< /Size %d /Root %d 0 R /Info %d 0 R >>\nstartxref\n%d\n%%%%EOF\n'
        % (len(objs) + 1, catalog, info, xref)
    )
    return bytes(out)
