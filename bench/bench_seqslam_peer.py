"""SeqSLAM whole run beside the C++ peer (TimQuelch/seqslam), alternating, quiet or loaded.

    python bench/bench_seqslam_peer.py --peer-bin /tmp/seqslam/build/peer-run            # 5 pairs
    python bench/bench_seqslam_peer.py --peer-bin /tmp/seqslam/build/peer-run --load 2   # + 2 busy processes
    python bench/bench_seqslam_peer.py --peer-bin ... --settings peer    # the peer's own benchmark's problem
    python bench/bench_seqslam_peer.py --write-driver /tmp/seqslam/driver                # the driver's source

The problem is ``bench_seqslam.py``'s: 3576 + 3576 64x32 thumbnails (nordland-dev tiled with
noise, the same PNG bytes for both programs), 11 query frames centred on the query (placeloc
``ds 10``, ``search: centred``; the peer's sequence length 11), slopes 0.8-1.2 (placeloc
``v_step 0.1``, five slopes of which four differ; the peer's 5 steps, which it reduces to
the slopes with distinct end points, 0.8, 1.0 and 1.2), contrast enhancement over 21
reference rows centred on the row (placeloc ``enhance_window 10``; the peer's window 21).
``--settings peer`` gives both programs the problem of the peer's own whole-run benchmark
instead (``benchmark-seqslam.cpp``: 15 query frames, slopes 0-5 in 10 steps, enhancement
over 30 rows, here 31 so that both centre it; placeloc ``ds 14``, ``v_step 5/9``,
``enhance_window 15``). Each program normalises the images its own way: placeloc patch normalisation (patch 8),
the peer OpenCV CLAHE (clip 20, its benchmark's value). Each pair runs both programs once,
the first of the two alternating from pair to pair, after one untimed run of each (which
fills placeloc's compiled-kernel cache and pocl's kernel cache, and the page cache).

What is timed, as whole processes (wall clock; CPU is user + sys of the children):

- placeloc: ``placeloc extract`` then ``placeloc localize``, two processes, as a user runs
  them: start-up and imports, reading the 7152 PNGs, patch normalisation, the SAD difference
  matrix, enhancement, sequence search, the ranking of 10 candidates per query, and writing
  ``extract.h5`` and ``localize.h5`` (D and enhanced D kept, as ``bench_seqslam.py`` does).
- the peer: one process of the driver below: the peer's ``readImages`` (OpenCV ``imread``),
  ``contrastEnhancement`` (CLAHE), ``convertToEigen``, then its ``cpu::`` (Eigen, one
  thread) or ``opencl::`` (one context, its three kernels built) ``generateDiffMx``,
  ``enhanceDiffMx`` and ``sequenceSearch``, then the best reference per query written to a
  text file.

Both programs' answers are checked against the truth of the tiled route (query frame i shows
the place of nordland-dev frame i mod 1200, as do reference frames i, i + 1200, ...): the
share of queries whose best reference is within 2 frames of a true one is printed, so a
timing of a run that did not solve the problem shows as such. The peer reads a folder in
``directory_iterator`` order, not sorted; its folders are written so that this order is the
route's order (files created first, then each frame written into the name at its place in
the listing).

Building the peer (nothing of it is in this repository). Debian 12 packages::

    apt-get install -y cmake g++ libeigen3-dev libopencv-dev libfmt-dev nlohmann-json3-dev \\
        libbenchmark-dev ocl-icd-opencl-dev opencl-headers opencl-clhpp-headers pocl-opencl-icd

Its files, from the public repository TimQuelch/seqslam: ``CMakeLists.txt``,
``src/seqslam.cpp``, ``include/seqslam.h``, ``src/measure.cpp``, ``include/measure.h``,
``src/demo.cpp`` at commit 036b8683e51e; ``include/clutils.h``, ``src/clutils.cpp`` at
1b478ce09f4a; ``include/utils.h``, ``src/utils.cpp``, ``config.json`` at 65d35b68e599;
``cmake/warnings.cmake`` at ef84f2f4e1aa; ``include/seqslam-detail.h`` (the version whose
declarations are ``noexcept``); ``src/kernels/diff-mx.cl`` (the version with
``tileSizeR``/``tileSizeQ`` and ``tr``/``tq``), ``src/kernels/enhancement.cl`` at
0690453c9287, ``src/kernels/search.cl`` (seven arguments, ``nPixPerThread``). Changes needed
to build them together on Debian 12:

1. ``include/clutils.h``: ``#define __CL_ENABLE_EXCEPTIONS`` / ``#include <CL/cl.hpp>``
   becomes ``CL_HPP_ENABLE_EXCEPTIONS``, ``CL_HPP_TARGET_OPENCL_VERSION 120``,
   ``CL_HPP_MINIMUM_OPENCL_VERSION 120``,
   ``CL_HPP_ENABLE_PROGRAM_CONSTRUCTION_FROM_ARRAY_COMPATIBILITY`` and
   ``#include <CL/opencl.hpp>`` (Debian ships no ``cl.hpp``).
2. ``include/seqslam.h``: the enhancement kernel names ``enhanceDiffMxSequential``,
   ``enhanceDiffMxStrided`` become ``enhanceDiffMx``, ``enhanceDiffMxOrig`` (the names in
   the stored ``enhancement.cl``; same arguments).
3. ``CMakeLists.txt``: ``enable_testing()``, ``add_subdirectory(test)`` and
   ``add_subdirectory(benchmark)`` left out (and the benchmarks' targets from its clang-tidy
   list), and the driver added::

       add_executable(peer-run driver/peer-run.cpp)
       target_link_libraries(peer-run PRIVATE seqslam fmt::fmt)

The peer has no command that runs one SeqSLAM on two folders (its ``demo`` sweeps
parameters over frames it drops; its benchmark times parts on fixed folders), so the driver
(``--write-driver DIR`` writes it; it is ours, it calls the peer's functions in the order of
its benchmark's ``cpuWhole``/``gpuWhole``) is the whole run. Then, as the peer's own build
(Release: ``-O3 -march=native``)::

    cmake -S seqslam -B seqslam/build -DCMAKE_BUILD_TYPE=Release && make -C seqslam/build peer-run

The ratio printed is the peer's time over placeloc's (the issue's goal: at least 2).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam import P, make_traverses, run_cli, write_config  # noqa: E402

from placeloc.core.images import list_images  # noqa: E402
from placeloc.experiments import shared_data_dir  # noqa: E402

# The problem, in placeloc's keys: ``placeloc`` is bench_seqslam.py's (the defaults, centred);
# ``peer`` is the whole run of the peer's own benchmark (benchmark-seqslam.cpp: 15 query
# frames, slopes 0-5 in 10 steps, an enhancement window of 30 rows, here 31 so that both
# programs centre it on the row).
SETTINGS = {
    "placeloc": {"ds": P.ds, "enhance_window": P.enhance_window, "v_min": P.v_min, "v_max": P.v_max,
                 "v_step": P.v_step},
    "peer": {"ds": 14, "enhance_window": 15, "v_min": 0.0, "v_max": 5.0, "v_step": 5 / 9},
}
PEER_CLAHE_CLIP = 20                     # the peer's benchmark (benchmark-seqslam.cpp) value
# The OpenCL work sizes of the peer's gpuWhole: diff-matrix tiles 4 x 4 with 8 pixels a
# work-item, 8 references a work-item in the enhancement, 6 in the search.
PEER_OPENCL_SIZES = ("4", "4", "8", "8", "6")
TRUTH_TOLERANCE = 2                      # frames

DRIVER_SOURCE = r'''// Whole-run driver for the TimQuelch/seqslam library (placeloc's bench/bench_seqslam_peer.py
// writes it; not the peer's code): the peer's functions in the order of its benchmark's
// cpuWhole / gpuWhole, on two folders, with the load and the answer, as one process.
// usage: peer-run opencl|cpu REF_DIR QUERY_DIR CLAHE_CLIP WINDOW SEQ_LEN V_MIN V_MAX N_TRAJ
//                 TILE_R TILE_Q N_PER_THREAD ENHANCE_PPT SEARCH_PPT OUT_FILE
// Run it from the build folder: the peer finds kernels/*.cl by walking up from the cwd.
#include "seqslam.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

using namespace seqslam;

namespace {
    using Clock = std::chrono::steady_clock;
    double since(Clock::time_point t0) {
        return std::chrono::duration<double>(Clock::now() - t0).count();
    }

    std::vector<std::string> listNames(std::filesystem::path const& dir) {
        // The same directory_iterator order as the peer's readImages (the folder is unchanged).
        std::vector<std::string> names;
        for (auto const& e : std::filesystem::directory_iterator(dir)) {
            names.push_back(e.path().filename().string());
        }
        return names;
    }
} // namespace

int main(int argc, char** argv) {
    if (argc != 16) {
        std::fprintf(stderr, "usage: %s opencl|cpu REF_DIR QUERY_DIR CLAHE_CLIP WINDOW SEQ_LEN V_MIN "
                     "V_MAX N_TRAJ TILE_R TILE_Q N_PER_THREAD ENHANCE_PPT SEARCH_PPT OUT_FILE\n", argv[0]);
        return 2;
    }
    std::string const path = argv[1];
    std::filesystem::path const refDir = argv[2];
    std::filesystem::path const queryDir = argv[3];
    double const clip = std::stod(argv[4]);
    unsigned const window = static_cast<unsigned>(std::stoul(argv[5]));
    unsigned const seqLen = static_cast<unsigned>(std::stoul(argv[6]));
    float const vMin = std::stof(argv[7]);
    float const vMax = std::stof(argv[8]);
    unsigned const nTraj = static_cast<unsigned>(std::stoul(argv[9]));
    std::size_t const tileR = std::stoul(argv[10]);
    std::size_t const tileQ = std::stoul(argv[11]);
    std::size_t const nPer = std::stoul(argv[12]);
    unsigned const enhancePpt = static_cast<unsigned>(std::stoul(argv[13]));
    unsigned const searchPpt = static_cast<unsigned>(std::stoul(argv[14]));
    std::filesystem::path const outFile = argv[15];

    auto const t0 = Clock::now();
    auto t = Clock::now();
    auto const ref = convertToEigen(contrastEnhancement(readImages(refDir), clip));
    auto const query = convertToEigen(contrastEnhancement(readImages(queryDir), clip));
    double const tLoad = since(t);

    Mx seq;
    double tContext = 0, tDiff = 0, tEnhance = 0, tSearch = 0;
    if (path == "opencl") {
        t = Clock::now();
        auto context = opencl::createContext();
        tContext = since(t);
        t = Clock::now();
        auto const d = opencl::generateDiffMx(context, ref, query, tileR, tileQ, nPer);
        tDiff = since(t);
        t = Clock::now();
        auto const e = opencl::enhanceDiffMx(context, d, window, enhancePpt);
        tEnhance = since(t);
        t = Clock::now();
        seq = opencl::sequenceSearch(context, e, seqLen, vMin, vMax, nTraj, searchPpt);
        tSearch = since(t);
    } else if (path == "cpu") {
        t = Clock::now();
        auto const d = cpu::generateDiffMx(ref, query);
        tDiff = since(t);
        t = Clock::now();
        auto const e = cpu::enhanceDiffMx(d, window);
        tEnhance = since(t);
        t = Clock::now();
        seq = cpu::sequenceSearch(e, seqLen, vMin, vMax, nTraj);
        tSearch = since(t);
    } else {
        std::fprintf(stderr, "path must be opencl or cpu, not %s\n", path.c_str());
        return 2;
    }

    // The answer: for each query, the reference with the lowest sequence score among the rows
    // the search filled (the peer leaves 0 where a trajectory would leave the matrix).
    t = Clock::now();
    auto const refNames = listNames(refDir);
    auto const queryNames = listNames(queryDir);
    auto const pad = static_cast<Eigen::Index>(std::ceil((seqLen / 2) * vMax)) + 1;
    std::ofstream out{outFile};
    for (Eigen::Index q = 0; q < seq.cols(); ++q) {
        Eigen::Index best = pad;
        for (Eigen::Index r = pad; r < seq.rows() - pad; ++r) {
            if (seq(r, q) < seq(best, q)) {
                best = r;
            }
        }
        out << queryNames[static_cast<std::size_t>(q)] << ' '
            << refNames[static_cast<std::size_t>(best)] << '\n';
    }
    out.close();
    double const tAnswer = since(t);
    std::fprintf(stderr, "peer %s: %zu x %zu, load+CLAHE %.3f s, context+kernel build %.3f s, "
                 "difference matrix %.3f s, enhancement %.3f s, search %.3f s, answer %.3f s, "
                 "total %.3f s\n", path.c_str(), ref.size(), query.size(), tLoad, tContext, tDiff,
                 tEnhance, tSearch, tAnswer, since(t0));
    return 0;
}
'''


def tile_period() -> int:
    """Frames after which ``make_traverses``' route repeats (its ``i % m``)."""
    data = shared_data_dir()
    if data is not None and (data / "nordland-dev").is_dir():
        return min(len(list_images(data / "nordland-dev" / s).paths) for s in ("summer", "winter"))
    return 1200


def frame_number(name: str) -> int:
    """``f123.png`` -> 123 (the names ``make_traverses`` writes)."""
    return int(re.fullmatch(r"f(\d+)\.png", name).group(1))


def share_correct(pairs: list[tuple[int, int]], period: int, tolerance: int = TRUTH_TOLERANCE) -> float:
    """Share of (query frame, answered reference frame) within ``tolerance`` frames of a true
    reference: query ``q`` shows the place of every reference ``r`` with ``r = q (mod period)``."""
    ok = 0
    for q, r in pairs:
        off = (r - q) % period
        ok += min(off, period - off) <= tolerance
    return ok / len(pairs)


def write_in_listing_order(frames: list[Path], folder: Path) -> None:
    """Copy ``frames`` into ``folder`` so that reading the folder in directory order (as
    ``std::filesystem::directory_iterator`` does) yields them in route order: create every
    name first, then write frame k into the k-th name of the listing (rewriting a file keeps
    its place)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(len(frames)):
        (folder / f"f{i}.png").touch()
    listed = [e.name for e in os.scandir(folder)]
    for src, name in zip(frames, listed):
        shutil.copyfile(src, folder / name)
    if [e.name for e in os.scandir(folder)] != listed:
        raise SystemExit(f"{folder}: the directory order changed while writing; use a folder on another file system")


def peer_answers(out_file: Path, ref_folder: Path, query_folder: Path) -> list[tuple[int, int]]:
    """The peer's (query frame, reference frame) pairs: its names mapped back to route frames."""
    ref_at = {e.name: k for k, e in enumerate(os.scandir(ref_folder))}
    query_at = {e.name: k for k, e in enumerate(os.scandir(query_folder))}
    pairs = []
    for line in out_file.read_text().splitlines():
        q, r = line.split()
        pairs.append((query_at[q], ref_at[r]))
    return pairs


def placeloc_answers(run_dir: Path) -> list[tuple[int, int]]:
    """placeloc's (query frame, best reference frame) pairs from ``localize.h5``."""
    import h5py

    with h5py.File(run_dir / "localize.h5", "r") as f:
        res = f["result"]
        q_names = [n.decode() if isinstance(n, bytes) else n for n in res["query_names"][()]]
        r_names = [n.decode() if isinstance(n, bytes) else n for n in res["reference_names"][()]]
        best = res["candidates"][:, 0]
    return [(frame_number(Path(q).name), frame_number(Path(r_names[b]).name)) for q, b in zip(q_names, best)]


def peer_problem(settings: dict) -> list[str]:
    """The peer's arguments for placeloc's ``settings``: ds + 1 query frames (placeloc's window),
    2 R + 1 enhancement rows (placeloc's +-R), the same slopes and their count."""
    n_slopes = round((settings["v_max"] - settings["v_min"]) / settings["v_step"]) + 1
    return [str(2 * settings["enhance_window"] + 1), str(settings["ds"] + 1), f"{settings['v_min']:g}",
            f"{settings['v_max']:g}", str(n_slopes)]


def run_peer(peer_bin: Path, path: str, ref: Path, query: Path, out_file: Path,
             problem: list[str]) -> tuple[float, float, str]:
    """One whole run of the peer as its own process: (wall s, CPU s, its timing line)."""
    sizes = PEER_OPENCL_SIZES if path == "opencl" else ("32", "32", "1", "1", "1")
    window, frames, v_min, v_max, n_slopes = problem
    args = [str(peer_bin), path, str(ref), str(query), str(PEER_CLAHE_CLIP), window, frames, v_min, v_max,
            n_slopes, *sizes, str(out_file)]
    before = os.times()
    t0 = time.perf_counter()
    done = subprocess.run(args, cwd=peer_bin.parent, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = os.times()
    if done.returncode != 0:
        raise SystemExit(f"{peer_bin}: exit {done.returncode}: {done.stderr.strip()[-400:]}")
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return wall, cpu, done.stderr.strip()


def run_placeloc(cfg: Path, run_dir: Path) -> tuple[float, float, float]:
    """``placeloc extract`` then ``placeloc localize``, each its own process:
    (wall s of both, CPU s of both, wall s of extract)."""
    wall = cpu = extract = 0.0
    for stage in ("extract", "localize"):
        w, c = run_cli([stage, str(cfg), "-o", str(run_dir), "-q", "-f"])
        wall, cpu = wall + w, cpu + c
        extract = extract or w
    return wall, cpu, extract


def start_load(k: int) -> list[subprocess.Popen]:
    """``k`` busy processes (a Python spin loop each) for the duration of the pairs."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(k)]


def stop_load(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        p.wait()


def spread(xs: list[float]) -> str:
    return f"median {statistics.median(xs):.2f} s, range {min(xs):.2f}-{max(xs):.2f} s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--peer-bin", type=Path, help="the driver built against the peer (see above)")
    ap.add_argument("--peer-path", choices=("cpu", "opencl"), default="cpu",
                    help="the peer's Eigen path (one thread) or its OpenCL kernels (pocl on the CPU here)")
    ap.add_argument("--pairs", type=int, default=5, help="alternating pairs timed")
    ap.add_argument("--load", type=int, default=0, help="busy processes running during the pairs")
    ap.add_argument("--n", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--settings", choices=tuple(SETTINGS), default="placeloc",
                    help="placeloc: bench_seqslam.py's problem; peer: the peer's own benchmark's window, frames, slopes")
    ap.add_argument("--work", type=Path, default=None, help="keep the images and runs here (default: a temporary folder)")
    ap.add_argument("--write-driver", type=Path, default=None, metavar="DIR",
                    help="only: write the driver's source to DIR/peer-run.cpp and stop")
    args = ap.parse_args()
    if args.write_driver is not None:
        args.write_driver.mkdir(parents=True, exist_ok=True)
        (args.write_driver / "peer-run.cpp").write_text(DRIVER_SOURCE)
        print(f"wrote {args.write_driver / 'peer-run.cpp'}")
        return
    if args.peer_bin is None or not os.access(args.peer_bin, os.X_OK):
        raise SystemExit(f"--peer-bin {args.peer_bin}: not an executable; build the peer's driver as this "
                         "script's docstring says (python bench/bench_seqslam_peer.py --help)")
    peer_bin = args.peer_bin.resolve()
    os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT / "pipeline"), os.environ.get("PYTHONPATH", "")])

    work = args.work or Path(tempfile.mkdtemp(prefix="placeloc-peer-"))
    try:
        ref, query = make_traverses(work / "placeloc", args.n)
        peer_ref, peer_query = work / "peer" / "reference", work / "peer" / "query"
        for src, dst in ((ref, peer_ref), (query, peer_query)):
            if not dst.is_dir():
                write_in_listing_order([src / f"f{i}.png" for i in range(args.n)], dst)
        settings = SETTINGS[args.settings]
        problem = peer_problem(settings)
        cfg = write_config(work / "config.json", ref, query, settings=settings)  # SAD, centred, trajectories, D kept
        run_dir, peer_out = work / "run", work / "peer-answers.txt"
        print(f"settings ({args.settings}): {args.n} x {args.n}, 64x32, {problem[1]} query frames centred, slopes "
              f"{problem[2]}-{problem[3]} ({problem[4]} steps), enhancement over {problem[0]} rows; peer path "
              f"{args.peer_path}, CLAHE clip {PEER_CLAHE_CLIP}")

        # One untimed run of each: placeloc's kernel cache, pocl's kernel cache, the page cache.
        run_placeloc(cfg, run_dir)
        *_, line = run_peer(peer_bin, args.peer_path, peer_ref, peer_query, peer_out, problem)
        period = tile_period()
        print(f"answers within {TRUTH_TOLERANCE} frames of the truth: placeloc "
              f"{share_correct(placeloc_answers(run_dir), period):.3f}, peer "
              f"{share_correct(peer_answers(peer_out, peer_ref, peer_query), period):.3f}")
        print(line, flush=True)

        load = start_load(args.load)
        pl_wall, pl_cpu, pl_extract, peer_wall, peer_cpu, ratios, loads = [], [], [], [], [], [], []
        try:
            for i in range(args.pairs):
                loads.append(os.getloadavg()[0])
                order = ("peer", "placeloc") if i % 2 == 0 else ("placeloc", "peer")
                for who in order:
                    if who == "peer":
                        w, c, line = run_peer(peer_bin, args.peer_path, peer_ref, peer_query, peer_out, problem)
                        peer_wall.append(w)
                        peer_cpu.append(c)
                    else:
                        w, c, e = run_placeloc(cfg, run_dir)
                        pl_wall.append(w)
                        pl_cpu.append(c)
                        pl_extract.append(e)
                loads.append(os.getloadavg()[0])
                ratios.append(peer_wall[-1] / pl_wall[-1])
                print(f"pair {i + 1} ({order[0]} first): placeloc {pl_wall[-1]:.2f} s (CPU {pl_cpu[-1]:.2f}), "
                      f"peer {peer_wall[-1]:.2f} s (CPU {peer_cpu[-1]:.2f}), ratio {ratios[-1]:.2f}, "
                      f"load {loads[-2]:.2f} -> {loads[-1]:.2f}", flush=True)
        finally:
            stop_load(load)
        print(f"\nplaceloc whole run (extract + localize, two processes): {spread(pl_wall)}; "
              f"CPU median {statistics.median(pl_cpu):.2f} s; extract median {statistics.median(pl_extract):.2f} s, "
              f"localize median {statistics.median([w - e for w, e in zip(pl_wall, pl_extract)]):.2f} s")
        print(f"peer whole run ({args.peer_path}, one process): {spread(peer_wall)}; "
              f"CPU median {statistics.median(peer_cpu):.2f} s")
        print(f"ratio peer / placeloc: median {statistics.median(ratios):.2f} over {args.pairs} pairs "
              f"(range {min(ratios):.2f}-{max(ratios):.2f}); ratio of the medians "
              f"{statistics.median(peer_wall) / statistics.median(pl_wall):.2f}; goal 2")
        print(f"{args.load} busy processes; 1-minute load average {min(loads):.2f}-{max(loads):.2f} "
              f"on {os.cpu_count()} cores")
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
