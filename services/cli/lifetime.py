"""A server started by another program ends with it: when the parent dies (a CI timeout, Ctrl-C on a test
run, a killed `make run`), the kernel signals the server, which logs why and starts the graceful shutdown
that SIGTERM starts, and that stops its Ray cluster and its inference process too. Before this, a pytest
run killed by `timeout` left a server and its Ray processes running for half an hour.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
from typing import Annotated

import typer

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_DIED = signal.SIGUSR2  # the kernel's notice; handled here, so a plain SIGTERM stays distinguishable

logger = logging.getLogger("uvicorn.error")  # where the server's own start and stop lines go

OutliveParent = Annotated[
    bool,
    typer.Option(
        "--outlive-parent/--die-with-parent",
        help="Keep running when the program that started this one exits (by default the server stops).",
    ),
]


def die_with_parent(sig: signal.Signals = signal.SIGTERM) -> bool:
    """Ask the kernel for a notice when the parent process exits (Linux), on which this process logs the
    reason and raises `sig` at itself; False where that is unavailable.

    A parent that died before the request leaves the process to init (or a subreaper) already: then the
    notice is acted on at once. Call from the main thread (it installs a signal handler).
    """
    if not sys.platform.startswith("linux"):
        return False
    parent = os.getppid()

    def parent_died(_signum, _frame) -> None:
        logger.warning(
            "stopping: the parent process %d exited (this server stops with the program that started it; "
            "`--outlive-parent` keeps it running)",
            parent,
        )
        signal.raise_signal(sig)

    signal.signal(PARENT_DIED, parent_died)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(PARENT_DIED), 0, 0, 0) != 0:
        signal.signal(PARENT_DIED, signal.SIG_DFL)
        return False
    if parent == 1 or os.getppid() != parent:
        parent_died(PARENT_DIED, None)
    return True
