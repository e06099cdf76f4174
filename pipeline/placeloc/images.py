"""Image folders: listing in natural order, fingerprints, loading with clear errors."""

from __future__ import annotations

import glob
import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import cv2

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


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
    # "stat": names, sizes and modification times (cheap; misses an edit that keeps both);
    # "content": a BLAKE2b hash of every file's bytes (reads every image once per run).
    fingerprint_mode: str = "stat"
    # One stat per file per process: every stage's stamp in a run sees the same listing.
    _stat_digest: str | None = field(default=None, repr=False, compare=False)

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
                h.update(f"{p.name}\0{content_hash(p)}\n".encode())
            return h.hexdigest()
        if self._stat_digest is None:
            for p in self.paths:
                st = os.stat(p)
                h.update(f"{p.name}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
            self._stat_digest = h.hexdigest()
        return self._stat_digest


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


def list_images(spec: str | Path, on_error: str = "stop", fingerprint: str = "stat") -> ImageSet:
    """List the images of a folder (or glob) in natural sort order."""
    spec = str(spec)
    p = Path(spec)
    if p.is_dir():
        # scandir's entry types come with the listing: no stat per file (is_file stats only links).
        with os.scandir(p) as entries:
            names = [e.name for e in entries if os.path.splitext(e.name)[1].lower() in IMAGE_EXTENSIONS and e.is_file()]
        files = [p / n for n in sorted(names, key=natural_key)]
    else:
        files = sorted((Path(q) for q in glob.glob(spec) if Path(q).suffix.lower() in IMAGE_EXTENSIONS),
                       key=lambda q: natural_key(q.name))
    if not files:
        raise ImageError(f"{spec}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)}); "
                         "point reference.images / query.images at a folder of images")
    return ImageSet(source=spec, paths=files, on_error=on_error, fingerprint_mode=fingerprint)


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


def read_gray(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit greyscale; colour is converted, 16-bit is scaled down."""
    import cv2  # here: stages that never decode an image do not pay for OpenCV's import

    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise ImageError(f"{path}: OpenCV cannot decode it ({' '.join(str(exc).split())[:200]}); "
                         "remove or replace it, or set on_error: skip beside images:") from exc
    if img is None or img.size == 0:
        raise _unreadable(path)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img


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
