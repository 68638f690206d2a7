"""`python -m tests.fuzz TARGET [TARGET ...] [libFuzzer flags]`: fuzz targets of `tests.fuzz.targets` with
atheris, each corpus started from its target's seeds, e.g. `python -m tests.fuzz gltf -max_total_time=60`.
A crash (any exception other than the parser's own 4xx error) ends a target's run with the input that
caused it, and the command's status is not 0.

Several targets run in child processes forked after the (instrumented) imports, one per core at a time:
the imports (usd-core, trimesh, the app: about 10 s on this machine) are paid once and their memory shared.
Each child's libFuzzer output goes to `<target>.log` in `$NBAKE_FUZZ_DIR` (or a temporary folder)."""

from __future__ import annotations

import os
import resource
import sys
import tempfile
from pathlib import Path

import atheris

with atheris.instrument_imports(include=["services", "workers"]):
    from tests.fuzz.targets import SEEDS, TARGETS, WORK_ENV

REPORT_CHARS = 3000
# The server parses an upload in a child process with an address-space ceiling (services/geometry.py): an
# importer that asks for more (usd-core's crate reader, given a few bytes, asks for gigabytes) fails with a
# MemoryError there, which the server answers 422. The same ceiling here, lower than the server's so that it
# acts before libFuzzer's -rss_limit_mb; a target starts at about 1.5 GB of address space.
MEMORY_BYTES = 4 << 30


def fuzz(name: str, flags: list[str], work: Path) -> None:
    """Run libFuzzer on target `name` in this process. It exits the process when done; a crash raises its
    exception, and libFuzzer's exit handler writes the input that caused it to `work/crash-<sha1>`."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))
    corpus = Path(tempfile.mkdtemp(prefix=f"corpus-{name}-", dir=work))
    for index, seed in enumerate(SEEDS[name].values()):
        (corpus / str(index)).write_bytes(seed)
    # A crashing input is written beside the corpus, never into the working directory.
    atheris.Setup([sys.argv[0], f"-artifact_prefix={work}/", *flags, str(corpus)], TARGETS[name])
    atheris.Fuzz()


def _started(name: str, flags: list[str], work: Path) -> int:
    """A forked child fuzzing `name`, its output in `work/<name>.log`: its pid."""
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        log = os.open(work / f"{name}.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(log, 1)
        os.dup2(log, 2)
        fuzz(name, flags, work)  # never returns: a crash leaves by an exception, which ends the child
    return pid


def fuzz_all(names: list[str], flags: list[str], work: Path, parallel: int) -> int:
    """Every target in a child of its own, `parallel` at a time; 1 if any crashed, after printing its log."""
    waiting, running, failed = list(names), {}, []
    while waiting or running:
        while waiting and len(running) < parallel:
            name = waiting.pop(0)
            running[_started(name, flags, work)] = name
        pid, status = os.wait()
        name = running.pop(pid)
        report = (work / f"{name}.log").read_text(errors="replace")
        report = "\n".join(line for line in report.splitlines() if not line.startswith("INFO: Instrumenting"))
        code = os.waitstatus_to_exitcode(status)
        if code != 0 or "Done" not in report:
            failed.append(name)
            print(f"== {name}: exit status {code}\n{report[-REPORT_CHARS:]}", flush=True)
        else:
            print(f"== {name}: {report.splitlines()[-1]}", flush=True)
    return 1 if failed else 0


def main(argv: list[str]) -> int:
    names = [arg for arg in argv if not arg.startswith("-")]
    flags = [arg for arg in argv if arg.startswith("-")]
    unknown = [name for name in names if name not in TARGETS]
    if not names or unknown:
        print(f"targets: {', '.join(TARGETS)} (unknown: {', '.join(unknown) or 'none given'})")
        return 2
    work = Path(os.environ.get(WORK_ENV) or tempfile.mkdtemp(prefix="nbake-fuzz-"))
    if len(names) == 1:
        fuzz(names[0], flags, work)
    return fuzz_all(names, flags, work, parallel=os.cpu_count() or 1)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
