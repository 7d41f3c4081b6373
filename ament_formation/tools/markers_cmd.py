"""`formation markers`: printable ArUco markers and a ChArUco calibration board at a stated size.

    formation markers --out markers.pdf --ids 0-5 [--marker-size-m 0.12] [--dictionary D]
    formation markers --out board.png --board 7x5,0.04,0.03[,DICT] [--dpi 300] [--page a4]
    formation markers --out refs.pdf --ids 40-44 --marker-size-m 0.15      # floor references

PDF (by the extension): vector rectangles at their exact places, one page per page, the viewer
asked not to scale. PNG: the pages rasterised at ``--dpi`` (edges within half a pixel), the DPI
stored in the file (pHYs) with a description of the sizes; several pages are written as
FILE-p1.png, FILE-p2.png, ... Every page says what is on it and carries a 100 mm bar to check the
print scale with a ruler.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import marker_sheet as ms
from ament_formation.core.vision.calibration import CharucoSpec


def _spec(args: argparse.Namespace) -> ms.SheetSpec:
    ids = ms.parse_ids(args.ids) if args.ids else ()
    board = CharucoSpec.parse(args.board) if args.board else None
    return ms.SheetSpec(
        marker_ids=ids,
        marker_size_m=args.marker_size_m,
        dictionary=args.dictionary,
        board=board,
        page_mm=ms.parse_page(args.page),
        margin_mm=args.margin_mm,
    )


def png_paths(out: Path, pages: int) -> list[Path]:
    """The file of each page: ``out`` itself for one page, else out-p1.png, out-p2.png, ..."""
    if pages == 1:
        return [out]
    return [out.with_name(f'{out.stem}-p{i + 1}{out.suffix}') for i in range(pages)]


def write_png(sheet: ms.Sheet, out: Path, dpi: float) -> list[Path]:
    """Each page of ``sheet`` as a PNG at ``dpi`` with its DPI and description stored."""
    from PIL import Image, PngImagePlugin

    paths = png_paths(out, len(sheet.pages))
    for i, (page, path) in enumerate(zip(sheet.pages, paths)):
        info = PngImagePlugin.PngInfo()
        info.add_text('Title', 'ament_formation markers')
        info.add_text('Description', f'{sheet.description}; page {i + 1}, {dpi:g} dpi')
        Image.fromarray(ms.rasterize(page, dpi)).save(path, dpi=(dpi, dpi), pnginfo=info)
    return paths


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in ('.png', '.pdf'):
        raise ConfigError(f'must end in .png or .pdf (got {args.out!r})', '--out')
    if not out.parent.is_dir():
        raise ConfigError('no such folder', '--out', str(out.parent))
    sheet = ms.layout(_spec(args))
    if suffix == '.pdf':
        out.write_bytes(ms.pdf_bytes(sheet))
        paths = [out]
    else:
        ms.rasterize(sheet.pages[0], args.dpi)  # validates --dpi before any file is written
        paths = write_png(sheet, out, args.dpi)
    print(sheet.description)
    for item in sheet.items:
        if item.kind != 'scale_bar':
            name = f'marker {item.ident}' if item.kind == 'marker' else 'board'
            print(
                f'  page {item.page + 1}: {name} at ({item.x_mm:.1f}, {item.y_mm:.1f}) mm, '
                f'{item.w_mm:.1f} x {item.h_mm:.1f} mm'
            )
    print('wrote ' + ', '.join(str(p) for p in paths))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'markers',
        help='printable ArUco markers and a ChArUco calibration board (PNG or PDF)',
        description='Write markers and/or a ChArUco board at their physical size, as a vector '
        'PDF or a PNG at a given DPI. Print at 100 %% and check the 100 mm bar with a ruler.',
    )
    p.add_argument('--out', required=True, metavar='FILE', help='FILE.pdf or FILE.png')
    p.add_argument(
        '--ids', default='', help="marker ids: 0-9, 0,1,5 or 0-3,7 (the robots' or the floor "
        'reference markers)'
    )
    p.add_argument(
        '--marker-size-m', type=float, default=0.12,
        help="side of the black square [m] (default 0.12, the tracker's marker_size_m)",
    )
    p.add_argument('--dictionary', default='DICT_4X4_50', help='ArUco dictionary (DICT_4X4_50)')
    p.add_argument(
        '--board', default='', metavar='SXxSY,SQUARE_M,MARKER_M[,DICT]',
        help='also a ChArUco board, as `formation calibrate intrinsics --board` takes it '
        '(e.g. 7x5,0.04,0.03)',
    )
    p.add_argument('--dpi', type=float, default=300.0, help='PNG resolution (default 300)')
    p.add_argument(
        '--page', default='a4', help=f'{", ".join(ms.PAGES_MM)} or WxH in mm (default a4)'
    )
    p.add_argument('--margin-mm', type=float, default=10.0, help='page margins [mm] (10)')
    p.set_defaults(func=run)
