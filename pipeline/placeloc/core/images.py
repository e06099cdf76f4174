"""Image folders: listing in natural order, fingerprints, loading with clear errors."""

from __future__ import annotations

import errno
import glob
import hashlib
import io
import os
import re
import stat
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import cv2

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
# Image formats placeloc does not read, though a camera, a browser or OpenCV may: their
# headers are not checked before decoding (the memory estimate needs the size up front), and
# animated or lossy-web formats are not frames of a traverse. A folder that holds one is
# listed without it, and a warning names it (synchronous ground truth refuses the folder).
OTHER_IMAGE_EXTENSIONS = (".webp", ".gif", ".avif", ".heic", ".heif", ".jp2", ".j2k", ".jpx", ".jxl", ".exr", ".hdr",
                          ".pic", ".pfm", ".pbm", ".pnm", ".pxm", ".sr", ".ras", ".jpe", ".jfif", ".dib", ".ico",
                          ".svg", ".psd", ".dng", ".cr2", ".nef", ".arw", ".raw")
# The first bytes of image files, to spot an image under another name ("frame7.png~", "frame8").
_IMAGE_SIGNATURES = (b"\x89PNG", b"\xff\xd8\xff", b"GIF8", b"BM", b"II*\x00", b"MM\x00*", b"P5", b"P6")


class ImageError(RuntimeError):
    """An image (or image folder) cannot be used; the message names the file and the fix."""


_DIGIT_RUNS = re.compile(r"(\d+)")


def natural_key(name: str) -> list:
    """Sort key under which img2 comes before img10."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in _DIGIT_RUNS.split(name)]


@dataclass
class ImageSet:
    """An ordered list of image files, as one traverse."""

    source: str
    paths: list[Path]
    on_error: str = "stop"
    skipped: list[str] = field(default_factory=list)
    # Files in the folder (or matched by the glob) that are not listed, with the reason:
    # (name, reason) for images of a format placeloc does not read and files that look like
    # images under another name; other files (CSV, notes, hidden files) are in ``others``.
    not_read: list[tuple[str, str]] = field(default_factory=list)
    others: list[str] = field(default_factory=list)
    # "stat": names, sizes and modification times (cheap; misses an edit that keeps both);
    # "content": a BLAKE2b hash of every file's bytes (reads every image once per run).
    fingerprint_mode: str = "stat"
    # One stat per file per process: every stage's stamp in a run sees the same listing, and
    # the per-image keys the extract stores (image_keys) are those the stamp hashed.
    _stat_digest: str | None = field(default=None, repr=False, compare=False)
    _stats: list[tuple[int, int]] | None = field(default=None, repr=False, compare=False)
    # fingerprint_mode "content": each file's hash, once per listing, shared by the stamp
    # (fingerprint) and the per-image keys the extract stores (image_keys), so a run reads
    # every image's bytes for hashing once, not twice.
    _content_hashes: dict[str, str] | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.paths)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.paths]

    def fingerprint(self) -> str:
        """SHA-256 over names, sizes and modification times (``stat``), or over names and a
        BLAKE2b hash of each file's bytes (``content``)."""
        h = hashlib.sha256()
        if self.fingerprint_mode == "content":
            for p in self.paths:
                h.update(f"{p.name}\0{self._content_hash(p)}\n".encode())
            return h.hexdigest()
        if self._stat_digest is None:
            for p, (size, mtime_ns) in zip(self.paths, self._file_stats()):
                h.update(f"{p.name}\0{size}\0{mtime_ns}\n".encode())
            self._stat_digest = h.hexdigest()
        return self._stat_digest

    def _file_stats(self) -> list[tuple[int, int]]:
        """(size, mtime_ns) of every listed file, once per listing."""
        if self._stats is None:
            self._stats = [(st.st_size, st.st_mtime_ns) for st in map(os.stat, self.paths)]
        return self._stats

    def _content_hash(self, path: Path) -> str:
        if self._content_hashes is None:
            self._content_hashes = {}
        if str(path) not in self._content_hashes:
            self._content_hashes[str(path)] = content_hash(path)
        return self._content_hashes[str(path)]

    def image_keys(self) -> list[str | None]:
        """One key per listed image, what :meth:`fingerprint` hashes of it: its name, size
        and modification time (``stat``), or its name and content hash (``content``). The
        extract stores them beside each image's rows, so a later run can take the rows of an
        image whose key is unchanged instead of describing it again
        (:mod:`placeloc.core.imagework`). None for a file that cannot be stat'ed or read
        now: it is described (and its error reported) as usual. Fields are joined by "/",
        which no file name holds (HDF5 strings end at a NUL)."""
        if self.fingerprint_mode == "content":
            keys: list[str | None] = []
            for p in self.paths:
                try:
                    keys.append(f"{p.name}/{self._content_hash(p)}")
                except (OSError, ImageError):
                    keys.append(None)
            return keys
        try:
            stats: list[tuple[int, int] | None] = list(self._file_stats())
        except OSError:   # a file gone since the listing: each one alone
            stats = [_stat_or_none(p) for p in self.paths]
        return [None if st is None else f"{p.name}/{st[0]}/{st[1]}" for p, st in zip(self.paths, stats)]


def _stat_or_none(path: Path) -> tuple[int, int] | None:
    """(size, mtime_ns) of a file, or None where it cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def content_hash(path: Path, block: int = 1 << 20) -> str:
    """BLAKE2b (16-byte digest) of a file's bytes."""
    h = hashlib.blake2b(digest_size=16)
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(block):
                h.update(chunk)
    except PermissionError as exc:
        raise ImageError(f"{path}: permission denied; make it readable (chmod a+r) or remove it") from exc
    return h.hexdigest()


# Listings of folders made in this process: (folder, on_error, fingerprint) -> (the
# folder's modification time and inode, the listing). A stage lists each traverse more than
# once (the ground-truth check, the runner's stamp); a folder whose entries change gets a
# new modification time and is listed again.
_LISTINGS: dict[tuple[str, str, str], tuple[tuple[int, int], ImageSet]] = {}


def list_images(spec: str | Path, on_error: str = "stop", fingerprint: str = "stat") -> ImageSet:
    """List the images of a folder (or glob) in natural sort order."""
    spec = str(spec)
    try:
        st = os.stat(spec)
    except OSError:
        st = None
    if st is not None and stat.S_ISDIR(st.st_mode):
        key, when = (spec, on_error, fingerprint), (st.st_mtime_ns, st.st_ino)
        known = _LISTINGS.get(key)
        if known is not None and known[0] == when:
            return _copy_listing(known[1])
        listing = _list_images(spec, on_error, fingerprint)
        _LISTINGS[key] = (when, listing)
        return _copy_listing(listing)
    return _list_images(spec, on_error, fingerprint)


def _copy_listing(images: ImageSet) -> ImageSet:
    """A caller's own ImageSet (its lists copied) of a listing kept in :data:`_LISTINGS`.
    Its fingerprint is taken afresh: an image edited in place keeps the folder's listing but
    must still change the stamp."""
    return replace(images, paths=list(images.paths), skipped=list(images.skipped), not_read=list(images.not_read),
                   others=list(images.others), _stat_digest=None, _stats=None, _content_hashes=None)


def _list_images(spec: str, on_error: str, fingerprint: str) -> ImageSet:
    p = Path(spec)
    skipped: list[str] = []

    def refuse(message: str) -> bool:
        if on_error == "skip":
            skipped.append(message)
            return False
        raise ImageError(message)

    def usable(folder: Path, name: str, entry: os.DirEntry | None = None) -> bool:
        """A regular file (or a link to one). A link loop is an error naming the link, or
        skipped (and recorded in the artifact) with on_error: skip."""
        try:
            # scandir's entry types come with the listing: no stat per file (is_file stats only links).
            return entry.is_file() if entry is not None else (folder / name).is_file()
        except OSError as exc:
            message = os_error_message(folder / name, exc)
        if on_error == "skip":
            skipped.append(message)
            return False
        raise ImageError(message)

    not_read: list[tuple[str, str]] = []
    others: list[str] = []

    def listed(folder: Path, name: str, entry: os.DirEntry | None = None) -> bool:
        """Listed as an image; when not, say why in ``not_read`` (an image placeloc does not
        read) or ``others`` (not an image). The suffix is read off the name: a Path made for
        every entry cost 0.05 s a listing of 3576 images."""
        if name.startswith("."):
            # Hidden files are never frames, as a shell's `*` (and glob) skips them: macOS
            # leaves a "._frame1.png" beside every file it copies to a foreign disk, some
            # of them valid images; listed, each would shift every later frame's index
            # against the ground truth, in silence.
            others.append(name)
            return False
        if os.path.splitext(name)[1].lower() in IMAGE_EXTENSIONS:
            if not is_utf8(name):
                return refuse(f"{folder}/{shown_name(name)}: the file name is not valid UTF-8 text (its "
                              "bytes are shown escaped); rename it in UTF-8 (e.g. convmv -f latin1 -t utf8 --notest "
                              "FILE), or set on_error: skip beside images:")
            return usable(folder, name, entry)
        reason = _why_not_read(folder / name, entry)
        if reason is None:
            others.append(name)
        else:
            not_read.append((name, reason))
        return False

    if p.is_dir():
        try:
            with os.scandir(p) as entries:
                names = [e.name for e in entries if listed(p, e.name, e)]
        except PermissionError as exc:
            raise ImageError(f"{spec}: the image folder cannot be listed (permission denied); "
                             "make it readable (chmod a+rx)") from exc
        files = [p / n for n in sorted(names, key=natural_key)]
    else:
        files = sorted((Path(q) for q in glob.glob(spec) if listed(Path(q).parent, Path(q).name)),
                       key=lambda q: natural_key(q.name))
    not_read.sort(key=lambda item: natural_key(item[0]))
    if not files:
        shown = f" (not read: {_first_names(not_read)})" if not_read else ""
        raise ImageError(f"{spec}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)}){shown}; "
                         "point reference.images / query.images at a folder of images")
    if not_read:
        _warn_once(spec, not_read)
    return ImageSet(source=spec, paths=files, on_error=on_error, fingerprint_mode=fingerprint, skipped=skipped,
                    not_read=not_read, others=sorted(others, key=natural_key))


def is_utf8(name: str) -> bool:
    """True when a file name decoded from the file system is valid UTF-8 (Python keeps the
    bytes of a name that is not as lone surrogates, which no text file, HDF5 string or
    report can hold)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def shown_name(name: str) -> str:
    """A file name as printable text: bytes that are not UTF-8 appear as \\xNN."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _why_not_read(path: Path, entry: os.DirEntry | None) -> str | None:
    """Why a file that is not listed would matter: an image of another format, or a file that
    starts like an image under a name without an image extension; None for other files."""
    ext = path.suffix.lower()
    if ext in OTHER_IMAGE_EXTENSIONS:
        return (f"{ext[1:].upper()} is not a format placeloc reads ({', '.join(e[1:] for e in IMAGE_EXTENSIONS)}); "
                "convert it (e.g. to PNG) or move it out")
    try:
        if entry is not None and not entry.is_file():
            return None  # a folder or a special file: not an image
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError:
        return None  # the listing only names files; an unreadable non-image is not ours to judge
    if head.startswith(_IMAGE_SIGNATURES) or (head[:4] == b"RIFF" and head[8:12] == b"WEBP") or head[4:8] == b"ftyp":
        return "its bytes are an image but its name has no image extension; rename it (e.g. .png) or move it out"
    return None


def _first_names(items: list[tuple[str, str]], n: int = 3) -> str:
    shown = ", ".join(name for name, _ in items[:n])
    return shown + (f" and {len(items) - n} more" if len(items) > n else "")


# One warning per folder and process: the runner and the ground-truth check list a folder more than once.
_WARNED: set[tuple[str, tuple[str, ...]]] = set()


def _warn_once(spec: str, not_read: list[tuple[str, str]]) -> None:
    import logging

    key = (spec, tuple(name for name, _ in not_read))
    if key in _WARNED:
        return
    _WARNED.add(key)
    logging.getLogger("placeloc.images").warning(
        "%s: %d file(s) not read: %s (%s)", spec, len(not_read), _first_names(not_read), not_read[0][1])


def check_position_pairing(reference: ImageSet, query: ImageSet, why: str = "ground_truth.kind: synchronous") -> None:
    """Refuse two listings that pair by position (query i is reference i) when something
    shifts the positions: different counts, a file of either folder not listed (an image of a
    format placeloc does not read, an unreadable entry skipped while listing), or folders
    that share file names but list them in different places. The message names the first
    mismatch; pairing the wrong files in silence turns a right answer into a wrong score."""
    for role, images in (("reference", reference), ("query", query)):
        if images.not_read:
            name, reason = images.not_read[0]
            raise ImageError(f"{role}.images: {name} is not read ({reason}); with {why} every later image would pair "
                             f"with the wrong one: convert or remove it (from both folders, to keep the pairs)")
        if images.skipped:
            raise ImageError(f"{role}.images: {images.skipped[0]} (skipped while listing); with {why} every later image "
                             "would pair with the wrong one: fix or remove it (from both folders, to keep the pairs)")
    r, q = reference.names, query.names
    shared = bool(set(r) & set(q))
    first = next((i for i, (a, b) in enumerate(zip(r, q)) if a != b), None) if shared else None
    if len(r) != len(q) or first is not None:
        where = (f"; the first difference is at position {first}: reference {r[first]} beside query {q[first]}"
                 if first is not None else "")
        raise ImageError(f"{why} pairs query i with reference i, but the reference lists {len(r)} images and the query "
                         f"{len(q)}{where}; give both folders the same frames (or use ground_truth.kind: csv or poses)")


# ----------------------------------------------------------------- headers

# Bytes a decode may hold per pixel: OpenCV's unchanged read (up to 4 channels of 16 bits),
# then the 8-bit, upright and grey/RGB copies made from it.
DECODE_BYTES_PER_PIXEL = 16


def image_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) from the header of a PNG, JPEG, BMP, PNM, TIFF, WebP or GIF file;
    None when the format is none of those or the header is damaged (the decoder then
    reports the file). Nothing is decoded."""
    # A raw descriptor and one 32-byte read: a buffered file object costs several times the
    # system calls, and every image of a traverse is checked before extract.
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        return _header_size(os.read(fd, 32), lambda: open(fd, "rb", closefd=False))
    except (OSError, ValueError, struct.error):
        return None
    finally:
        os.close(fd)


def image_size_of(data: bytes) -> tuple[int, int] | None:
    """:func:`image_size` of an encoded image already in memory."""
    try:
        return _header_size(data[:32], lambda: io.BytesIO(data))
    except (OSError, ValueError, struct.error):
        return None


def _header_size(head: bytes, open_stream: Any) -> tuple[int, int] | None:
    """(width, height) from an image's first 32 bytes ``head``; JPEG and the formats
    Pillow parses read on from ``open_stream()`` (opened only for them)."""
    size = _simple_size(head)
    if size is not None or not (head[:2] == b"\xff\xd8" or _pillow_format(head)):
        return size
    with open_stream() as fh:
        return _jpeg_size(fh) if head[:2] == b"\xff\xd8" else _pillow_size(fh, head)


def _simple_size(head: bytes) -> tuple[int, int] | None:
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])
    if head[:2] == b"BM" and len(head) >= 26:
        w, h = struct.unpack("<ii", head[18:26])
        return abs(w), abs(h)
    if head[:2] in (b"P5", b"P6", b"P2", b"P3"):
        fields = head[2:].split()
        return (int(fields[0]), int(fields[1])) if len(fields) >= 2 else None
    return None


def _pillow_format(head: bytes) -> str | None:
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "TIFF"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WEBP"
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return "GIF"
    return None


def _pillow_size(fh: Any, head: bytes) -> tuple[int, int] | None:
    """Pillow's own header parser for the format (its plugin class, which reads the header
    and none of the pixels; Image.open would also apply its decompression-bomb check, which
    is placeloc's to make, against the memory there is)."""
    import warnings

    from PIL import GifImagePlugin, TiffImagePlugin, WebPImagePlugin

    plugin = {"TIFF": TiffImagePlugin.TiffImageFile, "WEBP": WebPImagePlugin.WebPImageFile,
              "GIF": GifImagePlugin.GifImageFile}[_pillow_format(head) or ""]
    fh.seek(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            im = plugin(fh)
        except Exception:  # a damaged header: the decoder reports the file
            return None
    return int(im.size[0]), int(im.size[1])


def _jpeg_size(fh: Any) -> tuple[int, int] | None:
    fh.seek(2)
    for _ in range(10000):
        marker = fh.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        kind = marker[1]
        if kind in (0xD8, 0x01) or 0xD0 <= kind <= 0xD7:
            continue
        length = struct.unpack(">H", fh.read(2))[0]
        # SOF0..SOF15 carry the frame size, except DHT (C4), JPG (C8) and DAC (CC).
        if 0xC0 <= kind <= 0xCF and kind not in (0xC4, 0xC8, 0xCC):
            _, h, w = struct.unpack(">BHH", fh.read(5))
            return w, h
        fh.seek(length - 2, 1)
    return None


def _unreadable(path: str | Path) -> ImageError:
    """The reason cv2.imread returned nothing: missing, a folder, no permission, or bad bytes."""
    p = Path(path)
    if not p.exists():
        return ImageError(f"{path}: does not exist (deleted while the run was going?); restore it or re-run")
    if p.is_dir():
        return ImageError(f"{path}: is a folder, not an image; move it out of the image folder")
    if not os.access(p, os.R_OK):
        return ImageError(f"{path}: permission denied; make it readable (chmod a+r), or set on_error: skip beside images:")
    return ImageError(f"{path}: cannot be read as an image (corrupt or not an image); "
                      "remove or replace it, or set on_error: skip beside images:")


def os_error_message(path: str | Path, exc: OSError) -> str:
    """What an OSError on an image path means, with the fix (never Python's raw text)."""
    fix = "or set on_error: skip beside images:"
    if exc.errno == errno.ELOOP:
        return f"{path}: is a symbolic link that points to itself (a link loop); remove or fix the link, {fix}"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return f"{path}: permission denied; make it readable (chmod a+r), {fix}"
    if exc.errno == errno.ENOENT:
        return f"{path}: does not exist (a dangling link, or deleted while the run was going?); restore or remove it, {fix}"
    if exc.errno == errno.EISDIR:
        return f"{path}: is a folder, not an image; move it out of the image folder"
    return f"{path}: cannot be read ({exc.strerror or exc}); check the disk or the file, {fix}"


def _read_bytes(path: str | Path) -> bytes:
    """The file's bytes: a regular file (a FIFO or device put in place of an image is
    refused, not read until it ends) no larger than the memory there is.

    Plain descriptor calls, one read of the file's size: a Python file object (its own
    fstat, the blocking flag set back, a read until an empty one) took 18-21 us a file
    against 6-8 us, a fifth of SeqSLAM's extract of 7152 thumbnails."""
    from placeloc.core.safe_io import memory_budget

    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer (a regular file ignores it)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise ImageError(f"{path}: is not a regular file (a FIFO or device?); replace it with an image file, "
                                 "or set on_error: skip beside images:")
            budget = memory_budget() // 4
            if st.st_size > budget:
                raise ImageError(f"{path}: is {st.st_size / 2**20:.0f} MB, more than a quarter of the memory available "
                                 f"({budget * 4 / 2**20:.0f} MB); resize the images")
            data = os.read(fd, st.st_size + 1)
            if len(data) != st.st_size:  # a short read, or a file grown since: read on to its end
                parts = [data]
                while chunk := os.read(fd, 1 << 20):
                    parts.append(chunk)
                data = b"".join(parts)
            return data
        finally:
            os.close(fd)
    except OSError as exc:
        raise ImageError(os_error_message(path, exc)) from exc


def jpeg_is_complete(data: bytes) -> bool:
    """True when a JPEG's compressed data ends with its end-of-image marker. libjpeg
    decodes a truncated file (grey or repeated rows for the missing part) and only prints
    "Premature end of JPEG file", so the check is ours: walk the segments to the first
    start-of-scan (an EXIF thumbnail's own markers lie inside APP1 and are skipped), then
    look for end-of-image after it (0xFF inside scan data is always escaped as FF 00)."""
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return False
        kind = data[i + 1]
        if kind == 0xFF:  # fill byte
            i += 1
            continue
        if kind == 0xD9:
            return False  # end of image before any scan
        if kind in (0x01,) or 0xD0 <= kind <= 0xD7:
            i += 2
            continue
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if kind == 0xDA:  # start of scan: EOI must follow somewhere after it
            return data.find(b"\xff\xd9", i + 2 + length) >= 0
        i += 2 + length
    return False


# EXIF Orientation (tag 0x0112) -> how to turn the stored pixels upright: (rotate k x 90 deg
# counter-clockwise with np.rot90, then flip left-right). 1 is upright already.
_ORIENTATION = {2: (0, True), 3: (2, False), 4: (2, True), 5: (1, True), 6: (3, False), 7: (3, True), 8: (1, False)}


def exif_orientation(data: bytes) -> int:
    """The EXIF Orientation (1..8) of an encoded image (JPEG, PNG eXIf, TIFF, WebP); 1 when
    it has none. Read with Pillow from the header only (no decoding)."""
    if data[:2] != b"\xff\xd8" and data[:4] not in (b"II*\x00", b"MM\x00*") and data[:8] != b"\x89PNG\r\n\x1a\n":
        return 1
    # No EXIF block at all: skip Pillow, whose header parse (about 45 us a small PNG, with the
    # GIL held) cost more than decoding the frame. A JPEG's EXIF starts "Exif\0\0"; a PNG's is
    # an eXIf chunk or ImageMagick's "Raw profile type exif" text. A chance match only costs
    # the Pillow call.
    if data[:2] == b"\xff\xd8" and b"Exif\x00\x00" not in data:
        return 1
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"eXIf" not in data and b"Raw profile type exif" not in data:
        return 1
    import io

    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            value = im.getexif().get(0x0112, 1)
    except Exception:  # a damaged EXIF block: the decoder judges the pixels; no rotation
        return 1
    return int(value) if isinstance(value, int) and 1 <= value <= 8 else 1


@dataclass(frozen=True)
class PanoramaCrop:
    """Where a partial 360 degree photo lies in its whole equirectangular panorama, in the
    whole panorama's pixels, as Google's Photo Sphere XMP metadata (the GPano namespace)
    records it: a phone's photo sphere that did not cover the whole sphere is stored
    cropped to what it covered, with these six numbers beside it."""

    full_width: int
    full_height: int
    left: int
    top: int
    width: int
    height: int


GPANO_FIELDS = ("FullPanoWidthPixels", "FullPanoHeightPixels", "CroppedAreaLeftPixels", "CroppedAreaTopPixels",
                "CroppedAreaImageWidthPixels", "CroppedAreaImageHeightPixels")
XMP_SEARCH_BYTES = 1 << 20       # the XMP packet sits in the file's first segments


def _gpano_value(xmp: bytes, name: str) -> str | None:
    """One GPano property of an XMP packet, written as an attribute (GPano:X="1") or as an
    element (<GPano:X>1</GPano:X>)."""
    m = re.search(rb"GPano:" + name.encode() + rb"""\s*=\s*["']([^"']*)["']""", xmp) or \
        re.search(rb"<GPano:" + name.encode() + rb">\s*([^<]*?)\s*</GPano:" + name.encode() + rb">", xmp)
    return m.group(1).decode("utf-8", "replace").strip() if m else None


def panorama_crop(path: str | Path) -> PanoramaCrop | None:
    """The Photo Sphere crop of an image file (:class:`PanoramaCrop`), or None where it has
    no GPano metadata. A projection other than equirectangular, a value that is not a whole
    number, or a crop that does not fit its whole panorama is an :class:`ImageError` that
    names the file and the values."""
    try:
        with open(path, "rb") as f:
            head = f.read(XMP_SEARCH_BYTES)
    except OSError as exc:
        raise ImageError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if b"GPano:" not in head:
        return None
    projection = _gpano_value(head, "ProjectionType")
    if projection is not None and projection.lower() != "equirectangular":
        raise ImageError(f"{path}: its Photo Sphere metadata says GPano:ProjectionType {projection!r}; only "
                         "equirectangular panoramas are read: export the photo as an equirectangular image")
    values = {k: _gpano_value(head, k) for k in GPANO_FIELDS}
    if any(v is None for v in values.values()):
        return None
    try:
        crop = PanoramaCrop(*(int(float(values[k])) for k in GPANO_FIELDS))   # type: ignore[arg-type]
    except (ValueError, OverflowError):   # not a number; inf
        raise ImageError(f"{path}: its Photo Sphere metadata (GPano) holds a value that is not a number: "
                         f"{', '.join(f'{k}={v}' for k, v in values.items())}") from None
    fits = (crop.full_width > 0 and crop.full_height > 0 and abs(crop.full_width - 2 * crop.full_height) <= 2
            and 0 < crop.width <= crop.full_width and 0 < crop.height and 0 <= crop.top
            and crop.top + crop.height <= crop.full_height and 0 <= crop.left < crop.full_width)
    if not fits:
        raise ImageError(f"{path}: its Photo Sphere metadata (GPano) describes a crop that does not fit a 2:1 "
                         f"panorama: {', '.join(f'{k}={v}' for k, v in values.items())}")
    return crop


def upright(img: np.ndarray, orientation: int) -> np.ndarray:
    """Apply an EXIF orientation to pixels stored as they came off the sensor."""
    if orientation not in _ORIENTATION:
        return img
    k, flip = _ORIENTATION[orientation]
    if flip:
        img = img[:, ::-1]
    return np.ascontiguousarray(np.rot90(img, k))


def decode_image(path: str | Path) -> np.ndarray:
    """Every image placeloc reads comes through here: the file's bytes are read once (an
    unreadable path, a link loop or a permission problem named with the fix), a truncated
    JPEG is refused (libjpeg would return it half grey with only a warning), OpenCV decodes
    the pixels unchanged (bit depth, channels), and the EXIF Orientation is applied, so an
    image a phone stored rotated with Orientation=3 or 6 reads upright, as any viewer shows it."""
    import cv2  # here: stages that never decode an image do not pay for OpenCV's import

    data = _read_bytes(path)
    if not data:
        raise ImageError(f"{path}: is empty (0 bytes); remove or replace it, or set on_error: skip beside images:")
    if data[:2] == b"\xff\xd8" and not jpeg_is_complete(data):
        raise ImageError(f"{path}: truncated JPEG (its data ends before the end-of-image marker: a copy or download "
                         "that did not finish); replace it, or set on_error: skip beside images:")
    size = image_size_of(data)
    if size is not None:  # the header's size against the memory there is, before any pixel is decoded
        from placeloc.core.safe_io import memory_budget

        need, budget = size[0] * size[1] * DECODE_BYTES_PER_PIXEL, memory_budget()
        if need > budget:
            raise ImageError(f"{path}: its header says {size[0]} x {size[1]} pixels; decoding it needs about "
                             f"{need / 2**30:.1f} GiB, more than the {budget / 2**30:.1f} GiB available (MemAvailable or "
                             "PLACELOC_MEMORY_LIMIT_MB); resize the images")
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise ImageError(f"{path}: OpenCV cannot decode it ({' '.join(str(exc).split())[:200]}); "
                         "remove or replace it, or set on_error: skip beside images:") from exc
    if img is None or img.size == 0:
        raise _unreadable(path)
    return upright(img, exif_orientation(data))


def _decode_8bit(path: str | Path) -> np.ndarray:
    """:func:`decode_image`, scaled to 8 bits (16-bit by its high byte, float by its range)."""
    import cv2

    img = decode_image(path)
    if img.dtype == np.uint16:
        return (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def read_gray(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit greyscale, upright (EXIF orientation applied); colour is
    converted, 16-bit is scaled down."""
    import cv2

    img = _decode_8bit(path)
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img


def read_rgb(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit RGB, upright (for figures)."""
    import cv2

    img = _decode_8bit(path)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)


def akaze_detector(threshold: float | None) -> cv2.Feature2D:
    """OpenCV's AKAZE detector (``threshold`` None: OpenCV's own default, 0.001). AKAZE lives
    in ``cv2`` in OpenCV 4.x and in ``cv2.xfeatures2d`` from OpenCV 5 on."""
    import cv2

    kwargs = {} if threshold is None else {"threshold": float(threshold)}
    if hasattr(cv2, "AKAZE_create"):
        return cv2.AKAZE_create(**kwargs)
    xf = getattr(cv2, "xfeatures2d", None)
    if xf is not None and hasattr(xf, "AKAZE_create"):
        return xf.AKAZE_create(**kwargs)
    raise ImageError("AKAZE is not available in this OpenCV build: install opencv-contrib-python-headless")
