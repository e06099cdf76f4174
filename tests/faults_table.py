"""``make faults``: run the fault tests on their own and print one row per case.

Columns: the case (test id), its outcome, the exit code and the last stderr line of the
last ``placeloc`` command the case ran (what a user would have seen), and the seconds the
case took. Cases record their command's outcome with ``record(rc, stderr)`` (see
tests/test_faults*.py); a case that ran no command shows "-".
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

LAST: list[tuple[int, str]] = []


def record(rc: int | None, stderr: str) -> None:
    """Called by a case after each placeloc command it ran."""
    lines = [ln.strip() for ln in (stderr or "").splitlines() if ln.strip()]
    LAST.append((rc if rc is not None else -1, lines[-1] if lines else ""))


def stderr_of(result) -> str:
    """What a CliRunner result printed on stderr (its whole output where it keeps one stream)."""
    return getattr(result, "stderr", "") or result.output


def run_cli(args: list[str], **env: str):
    """Run ``placeloc ARGS`` in this process (typer's CliRunner) with ``env`` set, record
    its outcome for the table, and give the result."""
    import logging

    from typer.testing import CliRunner

    from placeloc.cli import app

    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    try:
        result = CliRunner().invoke(app, args, env=env or None)
        record(result.exit_code, stderr_of(result))
        return result
    finally:
        # the CLI points logging at CliRunner's stream, which is closed afterwards
        root.handlers[:], root.level = saved


def child_pids(pid: int) -> list[int]:
    """Every descendant process of ``pid`` (empty once it is gone)."""
    import psutil

    try:
        return [c.pid for c in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


# How long a case waits for an event before it calls the wait a hang. Only a guard against
# a hang: no case depends on an event coming sooner than this (a loaded machine is slow, not wrong).
HANG_S = 300


def wait_for(happened, what: str, limit_s: float = HANG_S) -> None:
    """Wait until ``happened()`` is true (polled every 50 ms); a failure names ``what``
    only if it has not happened after ``limit_s``, which is there to catch a hang."""
    end = time.monotonic() + limit_s
    while not happened():
        if time.monotonic() > end:
            raise AssertionError(f"{what} did not happen within {limit_s:.0f} s (a hang?)")
        time.sleep(0.05)


def ignores_sigint(pid: int) -> bool:
    """True when the process ignores SIGINT (bit 2 of SigIgn in /proc/PID/status): a worker
    that has reached the point where Ctrl-C no longer reaches it."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigIgn:"):
                return bool(int(line.split()[1], 16) & (1 << (2 - 1)))
    except OSError:
        return False
    return False


def workers_of(pid: int) -> list[int]:
    """The worker processes (spawned Python children, not the resource tracker) of ``pid``."""
    import psutil

    out = []
    for child in child_pids(pid):
        try:
            cmd = " ".join(psutil.Process(child).cmdline())
        except psutil.Error:
            continue
        if "spawn_main" in cmd and "resource_tracker" not in cmd:
            out.append(child)
    return out


def wait_gone(pids: list[int], limit_s: float = HANG_S) -> list[int]:
    """Wait until every process in ``pids`` has exited (zombies count as gone); returns the
    ones still alive after ``limit_s`` (a guard against a hang, not a speed requirement)."""
    import psutil

    def alive() -> list[int]:
        out = []
        for pid in pids:
            try:
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    out.append(pid)
            except psutil.NoSuchProcess:
                pass
        return out

    end = time.monotonic() + limit_s
    while alive() and time.monotonic() < end:
        time.sleep(0.05)
    return alive()


def start_pooled_run(tmp_path: Path, frames: int = 600, run_dir: Path | None = None):
    """``placeloc run`` of a generated route on a process pool of 2, in a session of its own
    (so a signal to its group reaches it as a terminal's Ctrl-C does) with TMPDIR in
    tmp_path; returned (process, TMPDIR) once extract has begun (its staging folder exists)
    and both workers ignore Ctrl-C: events, not a time, so a loaded machine only waits longer."""
    import subprocess

    from placeloc.synth.route import generate

    generate(tmp_path / "data", seed=2, frames=frames)
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    run = run_dir or tmp_path / "run"
    cmd = [sys.executable, "-m", "placeloc.cli", "run", str(tmp_path / "data" / "config.yaml"), "--run-dir", str(run), "-q",
                      "--set", "executor.workers=2", "--set", "seqslam.images_per_task=2", "--set", "plots=false"]
    proc = subprocess.Popen(cmd, env={**os.environ, "TMPDIR": str(tmpdir)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)

    def extracting() -> bool:
        if proc.poll() is not None:
            return True
        workers = workers_of(proc.pid)
        return (len(workers) >= 2 and all(ignores_sigint(w) for w in workers)
                and bool(list(run.glob(".extract.outputs.tmp-*"))))

    wait_for(extracting, "the pooled run reaching extract with both workers started")
    assert proc.poll() is None, "the run finished before it could be interrupted"
    return proc, tmpdir


def _last() -> list[tuple[int, str]]:
    """The cases import this file as the module ``faults_table``; ``make faults`` runs it as
    ``__main__``: read the list the cases wrote to."""
    module = sys.modules.get("faults_table")
    return module.LAST if module is not None else LAST


class _Table:
    def __init__(self) -> None:
        self.rows: list[tuple[str, str, str, float, str]] = []

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        _last().clear()
        t0 = time.perf_counter()
        outcome = {"value": "passed"}
        item._faults_outcome = outcome
        yield
        seconds = time.perf_counter() - t0
        rc, line = _last()[-1] if _last() else ("-", "")
        self.rows.append((item.nodeid.split("::", 1)[-1], outcome["value"], str(rc), seconds, line))

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_makereport(self, item, call):
        rep = (yield).get_result()
        if rep.failed:
            item._faults_outcome["value"] = "FAILED"
        elif rep.skipped:
            item._faults_outcome["value"] = "skipped"

    def print_table(self) -> None:
        width = min(70, max(len(r[0]) for r in self.rows)) if self.rows else 10
        print(f"\n{'case':<{width}}  {'outcome':<7}  {'rc':>3}  {'seconds':>7}  last line")
        for case, outcome, rc, seconds, line in self.rows:
            flag = "!" if seconds > 10 else " "
            print(f"{case[:width]:<{width}}  {outcome:<7}  {rc:>3}  {seconds:6.1f}{flag}  {line[:110]}")
        slow = sum(1 for r in self.rows if r[3] > 10)
        print(f"{len(self.rows)} cases, {sum(r[1] == 'FAILED' for r in self.rows)} failed, "
              f"{slow} took over 10 s in all (set-up included; cases wait on events, bounded only against a hang)")


def main() -> int:
    here = Path(__file__).resolve().parent
    table = _Table()
    # every round's file: tests/test_faults.py, test_faults_round2.py, test_faults_round3_*.py
    rounds = sorted(str(p) for p in here.glob("test_faults*.py"))
    args = ["-q", "-p", "no:cacheprovider", *rounds, *sys.argv[1:]]
    rc = pytest.main(args, plugins=[table])
    table.print_table()
    return int(rc)


if __name__ == "__main__":
    sys.exit(main())
