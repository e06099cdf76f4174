"""Charts drawn straight into pixels with Pillow: the pictures evaluate writes on every run.

matplotlib costs about 0.4 s to import and 0.1 to 0.3 s a figure, whatever the data's size:
more than a small run's whole localize. The pictures evaluate draws each time are simple:
an axes box with ticks, labels and a title; lines, markers and a legend; an image with a
colour bar. Drawn here, each costs milliseconds. Charts are drawn at ``SS`` times the
size and reduced by a box filter, which smooths lines and markers; text is Pillow's own
FreeType font (Aileron), so no system font is needed, except for characters it lacks
(accented letters, Cyrillic, CJK in frame names): those texts take an installed font
(:data:`FALLBACK_FONTS`) where there is one.

Coordinates given to :class:`Canvas` are output pixels; :class:`Axes` maps data to them.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

SS = 2  # supersampling factor
# matplotlib's default colour cycle ("tab10"), so curves keep the colours readers know
CYCLE = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
         (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
# dash patterns (on, off, ...) in units of the line's width, after matplotlib's "-", "--", "-.", ":"
DASHES: dict[str, tuple[float, ...]] = {"-": (), "--": (3.7, 1.6), "-.": (6.4, 1.6, 1.0, 1.6), ":": (1.0, 1.65)}
DASHES_CYCLE = ("-", "--", "-.", ":")  # the styles of several curves, in turn
BLACK, GRID = (0, 0, 0), (222, 222, 222)
STAMP_FROM = 64  # markers: more than this many are stamped as one mask (Axes._stamp), fewer drawn one by one
Colour = tuple[int, int, int]


_FONTS = threading.local()


def font(pixels: float) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's bundled font, ``pixels`` high (em height) on the canvas drawn. One set per
    thread: pictures are drawn on threads (:mod:`placeloc.evaluation.pictures`), and a
    FreeType face is not to be used by two threads at once."""
    fonts = getattr(_FONTS, "by_size", None)
    if fonts is None:
        fonts = _FONTS.by_size = {}
    if pixels not in fonts:
        fonts[pixels] = ImageFont.load_default(pixels)
    return fonts[pixels]


# Fonts for text Pillow's bundled font cannot draw: it covers ASCII and a few signs (degree,
# micro), not accented letters, Cyrillic or CJK, so a frame named "Zürich_01.png" or
# "写真_01.png" showed boxes. The first installed one that has every missing character draws
# the whole text (one font a text: no mixed baselines). File names, searched for below FONT_DIRS.
FALLBACK_FONTS = ("DejaVuSans.ttf", "NotoSans-Regular.ttf", "NotoSansCJK-Regular.ttc", "NotoSansCJKjp-Regular.otf",
                  "NotoSansJP-Regular.otf", "SourceHanSans-Regular.otc", "ipagp.ttf", "ipag.ttf", "ipaexg.ttf",
                  "Arial Unicode.ttf", "arialuni.ttf", "ヒラギノ角ゴシック W3.ttc", "Hiragino Sans GB.ttc", "YuGothM.ttc",
                  "meiryo.ttc", "msgothic.ttc", "Arial.ttf", "arial.ttf", "segoeui.ttf")
FONT_DIRS = ("/usr/share/fonts", "/usr/local/share/fonts", "~/.local/share/fonts", "~/.fonts", "/Library/Fonts",
             "/System/Library/Fonts", "C:/Windows/Fonts")
_FALLBACK_LOCK = threading.Lock()
_fallback_paths: list[str] | None = None
_covering: dict[str, str | None] = {}  # a text's missing characters -> the font file that has them all (None: none)


def _installed_fallbacks() -> list[str]:
    """The :data:`FALLBACK_FONTS` found on this machine, in that order (looked for once)."""
    global _fallback_paths
    if _fallback_paths is None:
        import os

        wanted = {name.lower(): i for i, name in enumerate(FALLBACK_FONTS)}
        found: dict[int, str] = {}
        for top in FONT_DIRS:
            for root, _, files in os.walk(os.path.expanduser(top)):
                for f in files:
                    i = wanted.get(f.lower())
                    if i is not None and i not in found:
                        found[i] = os.path.join(root, f)
        _fallback_paths = [found[i] for i in sorted(found)]
    return _fallback_paths


def _has_glyphs(f: ImageFont.FreeTypeFont | ImageFont.ImageFont, chars: str) -> bool:
    """Whether ``f`` draws every character of ``chars`` as itself, not as its missing-glyph box."""
    def ink(ch: str) -> tuple:
        m = f.getmask(ch)
        return (m.size, bytes(np.asarray(m, np.uint8).ravel()) if m.size[0] * m.size[1] else b"")

    missing = ink("\uffff")  # a non-character: every font draws its missing-glyph box for it
    return all(ink(ch) != missing for ch in chars)


_lacks: dict[str, bool] = {}  # a character -> whether the bundled font lacks it (asked once each)


def _opens_with(path: str, chars: str) -> bool:
    """Whether the font file at ``path`` opens and has every character of ``chars``; a file
    that is not a font (empty, cut short, unreadable) is passed over, never an error: a
    picture's name tag is not worth a failed evaluate."""
    try:
        return _has_glyphs(ImageFont.truetype(path, 24), chars)
    except (OSError, ValueError):
        return False


def _missing(text: str) -> str:
    """The characters of ``text`` the bundled font lacks, each once, in order ("" for ASCII)."""
    if text.isascii():
        return ""
    out = []
    for ch in dict.fromkeys(text):
        if ch.isascii() or ch.isspace():
            continue
        if ch not in _lacks:
            _lacks[ch] = not _has_glyphs(font(24), ch)
        if _lacks[ch]:
            out.append(ch)
    return "".join(out)


def font_for(text: str, pixels: float) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """The font that draws ``text``: Pillow's bundled one, or for characters it lacks the first
    installed :data:`FALLBACK_FONTS` that has them all (if none has, the bundled one: boxes)."""
    lacking = _missing(text)
    if not lacking:
        return font(pixels)
    with _FALLBACK_LOCK:
        if lacking not in _covering:
            _covering[lacking] = next((path for path in _installed_fallbacks() if _opens_with(path, lacking)), None)
        path = _covering[lacking]
    if path is None:
        return font(pixels)
    fonts = getattr(_FONTS, "by_file", None)
    if fonts is None:
        fonts = _FONTS.by_file = {}
    if (path, pixels) not in fonts:
        fonts[path, pixels] = ImageFont.truetype(path, pixels)
    return fonts[path, pixels]


def text_width(text: str, size: float) -> float:
    """Width of ``text`` in output pixels."""
    return float(font_for(text, size * SS).getlength(text)) / SS


def save_png(image: Image.Image, path: str | Path, *, photo: bool = False) -> Path:
    """Write ``image`` as PNG under a temporary name and rename, so a killed run never
    leaves half a picture and a failed save (a full disk) leaves no temporary file.
    ``photo``: images or matrices, which zlib hardly shrinks: its fastest level.
    OpenCV encodes (not Pillow): the same zlib levels and sizes, but it lets go of the GIL,
    so pictures drawn on threads (:mod:`placeloc.evaluation.pictures`) encode side by side;
    Pillow's encoder held it (two encodes beside a Python thread took 2.7x one's time)."""
    import cv2

    from placeloc.core.artifacts import tmp_path_for

    path = Path(path)
    pixels = np.asarray(image.convert("RGB") if image.mode not in ("RGB", "L") else image)
    if pixels.ndim == 3:
        pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)  # OpenCV writes BGR
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1 if photo else 6]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.11
        # one row filter ("up") instead of libpng's adaptive choice among five: the encode took
        # a third to a half of the time (difference matrices 18 against 34 ms, strips 10
        # against 29 ms) for files 0-15 % larger
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    ok, encoded = cv2.imencode(".png", pixels, params)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode a {image.size[0]} x {image.size[1]} {image.mode} picture as PNG")
    tmp = tmp_path_for(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(encoded.data)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


class Canvas:
    """A white picture of ``width`` x ``height`` output pixels, drawn at ``ss`` times the
    size (1: no smoothing, for pictures of images and axis-parallel frames only)."""

    def __init__(self, width: int, height: int, ss: int = SS) -> None:
        self.width, self.height, self.ss = int(width), int(height), int(ss)
        self.image = Image.new("RGB", (self.width * self.ss, self.height * self.ss), "white")
        self.draw = ImageDraw.Draw(self.image)

    def text(self, x: float, y: float, text: str, size: float = 11, fill: Colour = BLACK, anchor: str = "la",
             box: Colour | None = None, pad: float = 2) -> None:
        """``anchor``: Pillow's two letters (horizontal l/m/r, vertical a(top)/m/s(baseline)/d);
        ``box``: a filled box of that colour behind the text. Lines of a text with line
        breaks stack away from the anchor (upwards from a bottom anchor)."""
        if "\n" in text:
            lines = text.split("\n")
            n, step = len(lines), size * 1.3
            for i, line in enumerate(lines):
                shift = {"a": i, "m": i - (n - 1) / 2}.get(anchor[1], i - (n - 1)) * step
                self.text(x, y + shift, line, size, fill, anchor, box, pad)
            return
        xy = (x * self.ss, y * self.ss)
        if box is not None:
            left, top, right, bottom = self.draw.textbbox(xy, text, font=font_for(text, round(size * self.ss)), anchor=anchor)
            p = pad * self.ss
            self.draw.rectangle((left - p, top - p, right + p, bottom + p), fill=box)
        self.draw.text(xy, text, font=font_for(text, round(size * self.ss)), fill=fill, anchor=anchor)

    def vertical_text(self, x: float, y: float, text: str, size: float = 11, fill: Colour = BLACK) -> None:
        """``text`` turned a quarter left (read bottom to top), centred on (x, y)."""
        f = font_for(text, round(size * self.ss))
        left, top, right, bottom = f.getbbox(text)
        mask = Image.new("L", (int(right - left) + 2, int(bottom - top) + 2), 0)
        ImageDraw.Draw(mask).text((1 - left, 1 - top), text, font=f, fill=255)
        mask = mask.transpose(Image.Transpose.ROTATE_90)
        self.image.paste(fill, (int(x * self.ss - mask.width / 2), int(y * self.ss - mask.height / 2)), mask)

    def rectangle(self, box: Sequence[float], outline: Colour | None = None, fill: Colour | None = None,
                  width: float = 1) -> None:
        x0, y0, x1, y1 = (v * self.ss for v in box)
        self.draw.rectangle((x0, y0, x1, y1), outline=outline, fill=fill, width=max(1, round(width * self.ss)))

    def paste(self, rgb: np.ndarray, x: float, y: float) -> None:
        """An RGB uint8 array of output-pixel size with its top left at (x, y)."""
        img = Image.fromarray(np.ascontiguousarray(rgb[..., :3]), "RGB")
        if self.ss != 1:
            img = img.resize((rgb.shape[1] * self.ss, rgb.shape[0] * self.ss), Image.Resampling.NEAREST)
        self.image.paste(img, (round(x * self.ss), round(y * self.ss)))

    def result(self) -> Image.Image:
        """The picture at output size."""
        return self.image if self.ss == 1 else self.image.reduce(self.ss)

    def save(self, path: str | Path, photo: bool = False) -> Path:
        return save_png(self.result(), path, photo=photo)


def nice_ticks(lo: float, hi: float, most: int = 7) -> np.ndarray:
    """Round tick values (1, 2, 2.5 or 5 times a power of ten) from ``lo`` to ``hi``, at most ``most``."""
    span = hi - lo
    if not np.isfinite(span) or span <= 0:
        return np.array([lo])
    raw = span / max(1, most - 1)
    power = 10.0 ** np.floor(np.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    first = np.ceil(lo / step - 1e-9) * step
    ticks = np.arange(first, hi + step * 1e-9, step)
    return np.round(ticks, 12) + 0.0  # + 0.0: no "-0" label


def tick_label(v: float, ticks: np.ndarray) -> str:
    """A tick's label with as many decimals as the step needs (0.0, 0.2, ...; 500, 1000)."""
    step = float(np.min(np.diff(ticks))) if len(ticks) > 1 else 1.0
    decimals = 0 if step >= 1 and float(step).is_integer() else max(1, int(-np.floor(np.log10(step) + 1e-9)))
    return f"{v:.{decimals}f}"


class Axes:
    """A data box on a canvas. ``box`` = (left, top, right, bottom) in output pixels;
    ``xlog``: logarithmic x; ``y_down``: y grows downwards (a matrix's rows)."""

    def __init__(self, canvas: Canvas, box: Sequence[float], xlim: tuple[float, float], ylim: tuple[float, float], *,
                 xlog: bool = False, y_down: bool = False) -> None:
        self.c = canvas
        self.left, self.top, self.right, self.bottom = (float(v) for v in box)
        self.xlim, self.ylim, self.xlog, self.y_down = xlim, ylim, xlog, y_down
        self.ytick_width = 0.0  # the widest y tick label, set by frame(): where the y label goes
        # where lines and markers were drawn (output pixels, a point every few pixels along
        # a line): what a legend placed "best" keeps clear of
        self._drawn: list[np.ndarray] = []

    def _x(self, x: np.ndarray) -> np.ndarray:
        """Data x to output pixels."""
        x = np.asarray(x, np.float64)
        lo, hi = self.xlim
        if self.xlog:
            x, lo, hi = np.log10(x), np.log10(lo), np.log10(hi)
        return self.left + (x - lo) / (hi - lo) * (self.right - self.left)

    def _y(self, y: np.ndarray) -> np.ndarray:
        y = np.asarray(y, np.float64)
        lo, hi = self.ylim
        t = (y - lo) / (hi - lo)
        return self.top + t * (self.bottom - self.top) if self.y_down else self.bottom - t * (self.bottom - self.top)

    def xy(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Data to supersampled canvas pixels."""
        return self._x(x) * self.c.ss, self._y(y) * self.c.ss

    def text(self, x: float, y: float, text: str, size: float = 11, *, dx: float = 0.0, dy: float = 0.0,
             **kwargs: Any) -> None:
        """``text`` at the data point (x, y), moved ``dx``, ``dy`` output pixels (y down the
        page): a value beside its bar or point, a name at a position. ``kwargs``: as
        :meth:`Canvas.text` (fill, anchor, box)."""
        self.c.text(float(self._x(np.asarray(x, np.float64))) + dx, float(self._y(np.asarray(y, np.float64))) + dy, text,
                    size, **kwargs)

    # ----------------------------------------------------------------- frame, ticks, labels
    def frame(self, xticks: Sequence[float], yticks: Sequence[float], *, xlabels: Sequence[str] | None = None,
              ylabels: Sequence[str] | None = None, grid: bool = True, size: float = 11) -> None:
        """Grid lines (under what is drawn next), the box, ticks and their labels."""
        xt, yt = np.asarray(xticks, np.float64), np.asarray(yticks, np.float64)
        xl = list(xlabels) if xlabels is not None else [tick_label(v, xt) for v in xt]
        yl = list(ylabels) if ylabels is not None else [tick_label(v, yt) for v in yt]
        d, k = self.c.draw, self.c.ss
        px, py = self._x(xt), self._y(yt)
        if grid:
            for x in px:
                d.line([(x * k, self.top * k), (x * k, self.bottom * k)], fill=GRID, width=k)
            for y in py:
                d.line([(self.left * k, y * k), (self.right * k, y * k)], fill=GRID, width=k)
        self.box()
        for x, label in zip(px, xl):
            d.line([(x * k, self.bottom * k), (x * k, (self.bottom + 4) * k)], fill=BLACK, width=k)
            self.c.text(x, self.bottom + 6, label, size, anchor="ma")
        self.ytick_width = max((text_width(label, size) for label in yl), default=0.0)
        for y, label in zip(py, yl):
            d.line([((self.left - 4) * k, y * k), (self.left * k, y * k)], fill=BLACK, width=k)
            self.c.text(self.left - 6, y, label, size, anchor="rm")

    def box(self) -> None:
        self.c.rectangle((self.left, self.top, self.right, self.bottom), outline=BLACK, width=1)

    def labels(self, xlabel: str = "", ylabel: str = "", title: str = "", *, size: float = 12.5,
               title_size: float = 13) -> None:
        """Axis labels and a title (call after :meth:`frame`: the y label clears the tick labels)."""
        mid_x, mid_y = (self.left + self.right) / 2, (self.top + self.bottom) / 2
        if xlabel:
            self.c.text(mid_x, self.bottom + 24, xlabel, size, anchor="ma")
        if ylabel:
            self.c.vertical_text(self.left - 12 - self.ytick_width - size * 0.7, mid_y, ylabel, size)
        if title:
            self.c.text(mid_x, self.top - 7, title, title_size, anchor="md")

    # ----------------------------------------------------------------- what is drawn in it
    def line(self, x: np.ndarray, y: np.ndarray, colour: Colour, width: float = 2.0, style: str = "-") -> None:
        """A polyline ``width`` output pixels wide, solid or dashed (``DASHES``)."""
        px, py = self.xy(x, y)
        ok = np.isfinite(px) & np.isfinite(py)
        px, py = _one_point_a_pixel(px[ok], py[ok], self.c.ss)
        self._record(px, py, joined=True)
        if len(px) < 2:
            return
        w = max(1, round(width * self.c.ss))
        pattern = DASHES.get(style, ())
        if not pattern:
            self.c.draw.line(list(zip(px.tolist(), py.tolist())), fill=colour, width=w, joint="curve")
            return
        for run in _dash_runs(px, py, [p * width * self.c.ss for p in pattern]):
            self.c.draw.line(run, fill=colour, width=w, joint="curve")

    def markers(self, x: np.ndarray, y: np.ndarray, colour: Colour, shape: str = "o", size: float = 7.0,
                edge: float = 2.0) -> None:
        """``shape``: o s ^ D v > x + | O (``size``: output pixels across; ``edge``: the width of
        x, +, | and of the hollow ring O)."""
        px, py = self.xy(x, y)
        ok = np.isfinite(px) & np.isfinite(py)
        self._record(px[ok], py[ok])
        r = size * self.c.ss / 2
        w = max(1, round(edge * self.c.ss))
        if ok.sum() > STAMP_FROM and shape in "os+x|":
            self._stamp(px[ok], py[ok], colour, shape, r, w)
            return
        d = self.c.draw
        for cx, cy in zip(px[ok].tolist(), py[ok].tolist()):
            if shape == "o":
                d.ellipse((cx - r, cy - r, cx + r, cy + r), fill=colour)
            elif shape == "s":
                d.rectangle((cx - r * 0.9, cy - r * 0.9, cx + r * 0.9, cy + r * 0.9), fill=colour)
            elif shape == "O":
                d.ellipse((cx - r, cy - r, cx + r, cy + r), outline=colour, width=w)
            elif shape in "^vD>":
                pts = {"^": [(cx, cy - r), (cx + r, cy + r * 0.8), (cx - r, cy + r * 0.8)],
                       "v": [(cx, cy + r), (cx + r, cy - r * 0.8), (cx - r, cy - r * 0.8)],
                       ">": [(cx + r, cy), (cx - r * 0.8, cy - r), (cx - r * 0.8, cy + r)],
                       "D": [(cx, cy - r), (cx + r * 0.8, cy), (cx, cy + r), (cx - r * 0.8, cy)]}[shape]
                d.polygon(pts, fill=colour)
            elif shape == "x":
                d.line([(cx - r, cy - r), (cx + r, cy + r)], fill=colour, width=w)
                d.line([(cx - r, cy + r), (cx + r, cy - r)], fill=colour, width=w)
            elif shape == "+":
                d.line([(cx - r, cy), (cx + r, cy)], fill=colour, width=w)
                d.line([(cx, cy - r), (cx, cy + r)], fill=colour, width=w)
            elif shape == "|":
                d.line([(cx, cy - r), (cx, cy + r)], fill=colour, width=w)
            else:
                raise ValueError(f"unknown marker {shape!r}")

    def _stamp(self, px: np.ndarray, py: np.ndarray, colour: Colour, shape: str, r: float, w: int) -> None:
        """Many markers at once: the shape as a pixel mask, set at every point by numpy and
        filled in one paste (one drawing call a marker cost more than the rest of a
        difference-matrix picture). ``r``: radius, ``w``: stroke width, supersampled pixels."""
        k = int(np.ceil(r))
        dy, dx = np.mgrid[-k:k + 1, -k:k + 1]
        half = max(w, 1) / 2
        shapes = {"o": dx ** 2 + dy ** 2 <= r * r,
                  "s": (np.abs(dx) <= r * 0.9) & (np.abs(dy) <= r * 0.9),
                  "x": (np.abs(np.abs(dx) - np.abs(dy)) <= half * np.sqrt(2)) & (np.abs(dx) <= r) & (np.abs(dy) <= r),
                  "+": ((np.abs(dx) <= half) & (np.abs(dy) <= r)) | ((np.abs(dy) <= half) & (np.abs(dx) <= r)),
                  "|": (np.abs(dx) <= half) & (np.abs(dy) <= r)}
        oy, ox = np.nonzero(shapes[shape])
        cx, cy = np.rint(px).astype(np.int64), np.rint(py).astype(np.int64)
        x0, y0 = int(cx.min()) - k, int(cy.min()) - k
        mask = np.zeros((int(cy.max()) - y0 + k + 1, int(cx.max()) - x0 + k + 1), np.uint8)
        mask[(cy[:, None] - y0 + oy[None, :] - k).ravel(), (cx[:, None] - x0 + ox[None, :] - k).ravel()] = 255
        self.c.image.paste(colour, (x0, y0), Image.fromarray(mask, "L"))

    def segments(self, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray, colour: Colour,
                 width: float = 1.0) -> None:
        """Unjoined straight segments (x0, y0) to (x1, y1), solid: walls, error lines. One
        drawing call each, after one transform of all of them (a polyline per segment through
        :meth:`line` cost 20 times more for a plan's thousand walls)."""
        ax0, ay0 = self.xy(x0, y0)
        ax1, ay1 = self.xy(x1, y1)
        ok = np.isfinite(ax0) & np.isfinite(ay0) & np.isfinite(ax1) & np.isfinite(ay1)
        for t in np.linspace(0.0, 1.0, 5):  # each segment's ends and three points between
            self._record(ax0[ok] + t * (ax1[ok] - ax0[ok]), ay0[ok] + t * (ay1[ok] - ay0[ok]))
        w = max(1, round(width * self.c.ss))
        line = self.c.draw.line
        for a, b, c, d in zip(ax0[ok].tolist(), ay0[ok].tolist(), ax1[ok].tolist(), ay1[ok].tolist()):
            line([(a, b), (c, d)], fill=colour, width=w)

    def arrows(self, x: np.ndarray, y: np.ndarray, angle_deg: np.ndarray, colour: Colour, length: float,
               width: float = 1.0) -> None:
        """Arrows of ``length`` output pixels from each (x, y) at ``angle_deg`` (counter-
        clockwise from +x, on the page as in the data: y up unless ``y_down``), whatever the
        data's scale: a heading, not a distance."""
        px, py = self.xy(x, y)
        t = np.radians(np.asarray(angle_deg, np.float64))
        k = self.c.ss
        dx, dy = np.cos(t) * length * k, (np.sin(t) if self.y_down else -np.sin(t)) * length * k
        ok = np.isfinite(px) & np.isfinite(py) & np.isfinite(dx)
        w = max(1, round(width * k))
        head = max(3.0 * k, length * k * 0.38)  # the head's length along the shaft
        d = self.c.draw
        for cx, cy, ux, uy in zip(px[ok].tolist(), py[ok].tolist(), dx[ok].tolist(), dy[ok].tolist()):
            tx, ty = cx + ux, cy + uy
            n = float(np.hypot(ux, uy)) or 1.0
            bx, by = ux / n * head, uy / n * head  # back along the shaft from the tip
            d.line([(cx, cy), (tx - bx * 0.5, ty - by * 0.5)], fill=colour, width=w)
            d.polygon([(tx, ty), (tx - bx - by * 0.45, ty - by + bx * 0.45), (tx - bx + by * 0.45, ty - by - bx * 0.45)],
                      fill=colour)

    def fill_between(self, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, colour: Colour, alpha: float) -> None:
        """The region between two curves over ``x``, ``alpha`` opaque."""
        if len(x) == 0:
            return
        px, plo = self.xy(x, lo)
        _, phi = self.xy(x, hi)
        xs, ys = np.r_[px, px[::-1]], np.r_[plo, phi[::-1]]
        x0, y0 = int(np.floor(xs.min())), int(np.floor(ys.min()))  # a mask over the region only
        mask = Image.new("L", (int(np.ceil(xs.max())) - x0 + 2, int(np.ceil(ys.max())) - y0 + 2), 0)
        ImageDraw.Draw(mask).polygon(list(zip((xs - x0).tolist(), (ys - y0).tolist())), fill=round(255 * alpha),
                                     outline=round(255 * alpha))
        self.c.image.paste(colour, (x0, y0), mask)

    def image(self, rgb: np.ndarray) -> None:
        """An RGB uint8 array stretched over the whole box: averaged where it has more
        pixels than the box, each cell a block where it has fewer (no smoothing between cells)."""
        import cv2

        w, h = round((self.right - self.left) * self.c.ss), round((self.bottom - self.top) * self.c.ss)
        shrink = rgb.shape[0] >= h and rgb.shape[1] >= w
        resized = cv2.resize(np.ascontiguousarray(rgb), (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_NEAREST)
        self.c.image.paste(Image.fromarray(resized, "RGB"), (round(self.left * self.c.ss), round(self.top * self.c.ss)))

    def _record(self, px: np.ndarray, py: np.ndarray, joined: bool = False) -> None:
        """Note drawn points (supersampled pixels in), for :meth:`legend`'s "best"; a
        ``joined`` polyline gets a point every 4 output pixels along each piece."""
        x, y = np.asarray(px, np.float64) / self.c.ss, np.asarray(py, np.float64) / self.c.ss
        if joined and len(x) > 1:
            steps = np.maximum(1, np.ceil(np.hypot(np.diff(x), np.diff(y)) / 4.0)).astype(np.int64)
            if int(steps.sum()) <= 200_000:
                at = np.repeat(np.arange(len(x) - 1), steps)
                t = (np.arange(len(at)) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps, steps)
                x, y = np.append(x[at] + t * (x[at + 1] - x[at]), x[-1]), np.append(y[at] + t * (y[at + 1] - y[at]), y[-1])
        self._drawn.append(np.column_stack([x, y]))

    def legend(self, entries: Sequence[LegendEntry], loc: str | Sequence[str] = "lower left", size: float = 11) -> None:
        """A framed legend in a corner of the box (``loc``: "lower left", "lower right",
        "upper left", "upper right"; or several in order of preference, or "best": all four,
        upper right first): of several, the corner whose box covers the fewest of the points
        and lines drawn so far, the first such in the order given (matplotlib's "best")."""
        if not entries:
            return
        sample_w, pad, row_h = 30.0, 6.0, size * 1.45
        width = sample_w + 3 * pad + max(text_width(e.label, size) for e in entries)
        height = row_h * len(entries) + pad

        def corner(where: str) -> tuple[float, float]:
            return (self.left + 8 if "left" in where else self.right - 8 - width,
                    self.bottom - 8 - height if "lower" in where else self.top + 8)

        corners = list(LEGEND_CORNERS) if loc == "best" else [loc] if isinstance(loc, str) else list(loc)
        x0, y0 = corner(corners[0])
        if len(corners) > 1:
            pts = np.concatenate(self._drawn) if self._drawn else np.zeros((0, 2))

            def covered(where: str) -> int:
                cx, cy = corner(where)
                return int(np.count_nonzero((pts[:, 0] >= cx - 3) & (pts[:, 0] <= cx + width + 3) &
                                            (pts[:, 1] >= cy - 3) & (pts[:, 1] <= cy + height + 3)))

            x0, y0 = corner(min(corners, key=covered))  # min keeps the first of equal counts
        self.c.rectangle((x0, y0, x0 + width, y0 + height), outline=(204, 204, 204), fill=(255, 255, 255), width=1)
        for i, e in enumerate(entries):
            cy = y0 + pad / 2 + row_h * (i + 0.5)
            _sample(self.c, x0 + pad, x0 + pad + sample_w, cy, e, size)
            self.c.text(x0 + 2 * pad + sample_w, cy, e.label, size, anchor="lm")


LEGEND_CORNERS = ("upper right", "upper left", "lower left", "lower right")  # "best" tries them in this order


class LegendEntry:
    """One row of a legend: a line sample (``line_width`` > 0) and/or a marker, or a short
    ``text`` in the colour (how a picture writes names), and its label."""

    def __init__(self, label: str, colour: Colour, *, line_width: float = 0.0, style: str = "-", marker: str = "",
                 marker_size: float = 7.0, text: str = "") -> None:
        self.label, self.colour, self.line_width, self.style = label, colour, line_width, style
        self.marker, self.marker_size, self.text = marker, marker_size, text


def _sample(c: Canvas, x0: float, x1: float, cy: float, e: LegendEntry, size: float) -> None:
    """A legend entry's sample between x0 and x1 (output pixels) on the row centred at cy."""
    if e.line_width:
        _line_in_pixels(c, [x0, x1], [cy, cy], e.colour, e.line_width, e.style)
    if e.marker:
        _marker_in_pixels(c, (x0 + x1) / 2, cy, e.colour, e.marker, e.marker_size)
    if e.text:
        c.text((x0 + x1) / 2, cy, e.text, size * 1.15, fill=e.colour, anchor="mm")


LEGEND_SAMPLE, LEGEND_PAD, LEGEND_GAP = 30.0, 6.0, 22.0  # a row legend's sample, its gap to the label, between entries


def legend_rows(entries: Sequence[LegendEntry], width: float, size: float = 11) -> list[list[LegendEntry]]:
    """The entries of a legend laid in rows across ``width`` output pixels, in order, as
    many to a row as fit (at least one)."""
    rows: list[list[LegendEntry]] = []
    used = width + 1.0
    for e in entries:
        w = _entry_width(e, size)
        if rows and used + w <= width:
            rows[-1].append(e)
            used += w
        else:
            rows.append([e])
            used = w
    return rows


def _entry_width(e: LegendEntry, size: float) -> float:
    return LEGEND_SAMPLE + LEGEND_PAD + text_width(e.label, size) + LEGEND_GAP


def legend_row_height(size: float = 11) -> float:
    return size * 1.6


def draw_legend_rows(c: Canvas, rows: Sequence[Sequence[LegendEntry]], top: float, size: float = 11) -> None:
    """Rows from :func:`legend_rows`, each centred on the canvas, the first at ``top``:
    a legend under the panels, out of the data's way."""
    for i, row in enumerate(rows):
        total = sum(_entry_width(e, size) for e in row) - LEGEND_GAP
        x = (c.width - total) / 2
        cy = top + legend_row_height(size) * (i + 0.5)
        for e in row:
            _sample(c, x, x + LEGEND_SAMPLE, cy, e, size)
            c.text(x + LEGEND_SAMPLE + LEGEND_PAD, cy, e.label, size, anchor="lm")
            x += _entry_width(e, size)


def _line_in_pixels(c: Canvas, xs: Sequence[float], ys: Sequence[float], colour: Colour, width: float, style: str) -> None:
    ax = Axes(c, (0, 0, 1, 1), (0, 1), (0, 1), y_down=True)  # identity: data are output pixels
    ax.line(np.asarray(xs), np.asarray(ys), colour, width, style)


def _marker_in_pixels(c: Canvas, x: float, y: float, colour: Colour, shape: str, size: float) -> None:
    ax = Axes(c, (0, 0, 1, 1), (0, 1), (0, 1), y_down=True)
    ax.markers(np.array([x]), np.array([y]), colour, shape, size)


def _one_point_a_pixel(px: np.ndarray, py: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A polyline's points (canvas pixels) without those that stay in the output pixel
    (``size`` canvas pixels a side) of the point before them; the last point is kept.
    Why: Pillow joins every vertex of a wide line in Python (an angle and a pie slice each),
    so a line's cost grew with its points, not with the pixels it covers: a PR curve at 3576
    queries is drawn from 800 points instead of 3567 (the chart 18 ms of CPU instead of
    21), and at any number of queries from about as many as the picture is wide. Points in
    one pixel move the line by less than a pixel."""
    if len(px) < 3:
        return px, py
    cell = np.floor(px / size) * 1e6 + np.floor(py / size)  # canvases are far smaller than 1e6 pixels a side
    keep = np.empty(len(px), bool)
    keep[0], keep[-1] = True, True
    np.not_equal(cell[1:-1], cell[:-2], out=keep[1:-1])
    return px[keep], py[keep]


def _dash_runs(px: np.ndarray, py: np.ndarray, pattern: Sequence[float]) -> list[list[tuple[float, float]]]:
    """The drawn pieces of a dashed polyline: points every pixel along it, kept where the
    distance travelled falls in an "on" part of ``pattern`` (on, off, on, off, ...)."""
    seg = np.hypot(np.diff(px), np.diff(py))
    total = float(seg.sum())
    if total <= 0:
        return []
    at = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, total, max(2, int(total) + 1))
    x, y = np.interp(s, at, px), np.interp(s, at, py)
    bounds = np.cumsum(pattern)
    phase = np.mod(s, bounds[-1])
    on = np.searchsorted(bounds, phase, side="right") % 2 == 0
    runs: list[list[tuple[float, float]]] = []
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        b = min(b + 1, len(s))  # to the first sample past the dash: a dash of 6 pixels is 6 long, not 5
        if b - a >= 2:
            runs.append(list(zip(x[a:b].tolist(), y[a:b].tolist())))
    return runs


def to_scale_box(lo: np.ndarray, hi: np.ndarray, most: float) -> tuple[float, float]:
    """The width and height in pixels of a data box from ``lo`` to ``hi`` (x, y) drawn to
    scale, its longer side ``most`` pixels (and its shorter at least a fifth of that: the
    caller widens the short side's limits to keep the scale)."""
    span = np.maximum(np.asarray(hi, float) - np.asarray(lo, float), 1e-9)
    s = most / float(span.max())
    return max(span[0] * s, most / 5), max(span[1] * s, most / 5)


def titled_chart(title: str, box_w: float, box_h: float, entries: Sequence[LegendEntry], xlim: tuple[float, float],
                  ylim: tuple[float, float], xlabel: str, ylabel: str, *, xticks: Sequence[float] | None = None,
                  xtick_labels: Sequence[str] | None = None,
                  yticks: Sequence[float] | None = None) -> tuple[Canvas, Axes, list[list[LegendEntry]]]:
    """A canvas with one data box of ``box_w`` x ``box_h`` pixels under a title of one or
    more lines, its legend in rows below (drawn by :func:`legend_below` once the data are
    in); the box framed with ticks (round ones unless given)
    and labels. Returns the canvas, the axes and the legend's rows."""
    lines = title.split("\n")
    width = int(max(box_w + 120, max(text_width(t, 14) for t in lines) + 40, 520))
    rows = legend_rows(entries, width - 40, size=12)
    top = 18.0 + 18.0 * len(lines)
    c = Canvas(width, int(top + box_h + 54 + legend_row_height(12) * len(rows) + 6))
    left = round(84 + max(0.0, (width - 120 - box_w) / 2))
    ax = Axes(c, (left, round(top), round(left + box_w), round(top + box_h)), xlim, ylim)
    ax.frame(nice_ticks(*xlim, most=max(3, int(box_w / 90))) if xticks is None else xticks,
             nice_ticks(*ylim, most=max(3, int(box_h / 70))) if yticks is None else yticks, xlabels=xtick_labels,
             size=12)
    ax.labels(xlabel, ylabel, size=13)
    for i, t in enumerate(lines):
        c.text(width / 2, 26 + 18 * i, t, 14, anchor="ms")
    return c, ax, rows


def legend_below(c: Canvas, ax: Axes, rows: Sequence[Sequence[LegendEntry]]) -> None:
    """The legend rows of :func:`titled_chart` under its box, clear of the x label."""
    draw_legend_rows(c, rows, ax.bottom + 48, size=12)


def percentiles(values: np.ndarray, qs: Sequence[float]) -> tuple[float, ...]:
    """``np.percentile(values, qs)`` (linear between the two nearest ranks) by partition:
    np.percentile's np.unique would import numpy.ma (20 ms) for a colour scale's two ends."""
    v = np.asarray(values).ravel()
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    pos = [q / 100 * (len(v) - 1) for q in qs]
    ranks = sorted({int(np.floor(p)) for p in pos} | {int(np.ceil(p)) for p in pos})
    # partitioned in the values' own precision (a float32 matrix: half the memory to move),
    # the ranks' values widened to float64 before interpolating: the results of before
    part = np.partition(v, ranks)
    at = {r: float(part[r]) for r in ranks}
    return tuple(float(at[int(np.floor(p))] + (at[int(np.ceil(p))] - at[int(np.floor(p))]) * (p - np.floor(p))) for p in pos)


def grey_image(matrix: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """A matrix as an RGB grey image, ``vmin`` black to ``vmax`` white (NaN white, as an
    empty cell on a white page)."""
    scale = 255.0 / (vmax - vmin) if vmax > vmin else 0.0
    with np.errstate(invalid="ignore"):
        g = np.clip((np.asarray(matrix, np.float32) - vmin) * scale, 0, 255)
    g = np.where(np.isfinite(g), g, 255).round().astype(np.uint8)
    return np.repeat(g[..., None], 3, axis=2)


def colour_bar(c: Canvas, box: Sequence[float], vmin: float, vmax: float, label: str, size: float = 11) -> None:
    """A vertical grey scale from ``vmin`` (bottom, black) to ``vmax`` (top, white) with ticks on the right."""
    left, top, right, bottom = box
    h = max(2, round((bottom - top) * c.ss))
    ramp = np.linspace(255, 0, h).round().astype(np.uint8)
    bar = np.repeat(np.repeat(ramp[:, None], max(1, round((right - left) * c.ss)), axis=1)[..., None], 3, axis=2)
    c.image.paste(Image.fromarray(bar, "RGB"), (round(left * c.ss), round(top * c.ss)))
    ax = Axes(c, box, (0, 1), (vmin, vmax) if vmax > vmin else (vmin, vmin + 1))
    ax.box()
    ticks = nice_ticks(*ax.ylim, most=10)
    for v, y in zip(ticks, ax._y(ticks)):
        c.draw.line([(right * c.ss, y * c.ss), ((right + 4) * c.ss, y * c.ss)], fill=BLACK, width=c.ss)
        c.text(right + 6, y, tick_label(v, ticks), size, anchor="lm")
    widest = max(text_width(tick_label(v, ticks), size) for v in ticks)
    c.vertical_text(right + 12 + widest + size * 0.8, (top + bottom) / 2, label, size)
