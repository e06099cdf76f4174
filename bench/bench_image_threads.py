"""Per-image reading over threads, by image size: where ``imagework.SMALL_IMAGE_PIXELS`` comes from.

    python bench/bench_image_threads.py                  # 64x32, 128x64, 256x128 PNGs; 1, 2, 4, ..., nproc threads
    python bench/bench_image_threads.py --n 2000 --threads 1,2

SeqSLAM's per-image work (read, decode, greyscale, thumbnail) on ``--n`` frames of each
size, in one process, the frames cut into ``threads`` contiguous parts each described on a
thread (``imagework.describe_chunk``, what every extract task runs), best of ``--repeat``
after a warm-up pass (page cache). The per-image work around the decoder holds the GIL;
decoding and file reading release it, so threads pay only where the decode outweighs the
rest: the table shows from which size on. Frames are the synthetic route generator's, or
nordland-dev's when present (as ``bench_seqslam.make_traverses``), resized.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipeline"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from scaling import counts_from, markdown, scaling_table  # noqa: E402

from placeloc.core.images import list_images, read_gray  # noqa: E402
from placeloc.core.imagework import SMALL_IMAGE_PIXELS, describe_chunk  # noqa: E402
from placeloc.seqslam.features import feature_work  # noqa: E402
from placeloc.seqslam.params import SeqSLAMParams  # noqa: E402


def frames_of_size(source: list[Path], out: Path, size: tuple[int, int]) -> list[str]:
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, p in enumerate(source):
        dst = out / f"{i:06d}.png"
        cv2.imwrite(str(dst), cv2.resize(read_gray(p), size, interpolation=cv2.INTER_LINEAR))
        paths.append(str(dst))
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3576, help="frames of each size")
    ap.add_argument("--sizes", default="64x32,128x64,256x128", help="comma list of WxH")
    ap.add_argument("--threads", default=None, help="thread counts (default 1, 2, 4, ..., nproc)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    from bench_seqslam import make_traverses

    p = SeqSLAMParams()
    work_item = feature_work(thumbnail_size=p.thumbnail, comparison=p.comparison, patch=p.patch, normalisation=p.normalisation,
                             gaussian_sigma=p.gaussian_sigma, ocm_epsilon=p.ocm_epsilon)
    tmp = Path(tempfile.mkdtemp(prefix="placeloc-image-threads-"))
    table: dict[str, dict[int, float]] = {}
    try:
        ref, _ = make_traverses(tmp / "source", args.n)
        source = list_images(ref).paths
        for spec in args.sizes.split(","):
            w, h = (int(v) for v in spec.split("x"))
            paths = frames_of_size(source, tmp / spec, (w, h))

            def measure(k: int, paths: list[str] = paths, spec: str = spec) -> dict[str, float]:
                t0 = time.perf_counter()
                describe_chunk((paths, work_item, False, k))
                return {f"{spec}, {len(paths)} frames": time.perf_counter() - t0}

            table.update(scaling_table(measure, counts_from(args.threads), args.repeat))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print()
    print(markdown(table, "SeqSLAM per-image work, one process", unit="thread",
                   note=f"Best of {args.repeat} after a warm-up. Images under {SMALL_IMAGE_PIXELS} pixels are described on "
                        "one thread per task (imagework.SMALL_IMAGE_PIXELS)."))


if __name__ == "__main__":
    main()
