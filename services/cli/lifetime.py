"""A server started by another program ends with it: when the parent dies (a CI timeout, Ctrl-C on a test
run, a killed `make run`), the kernel sends the server SIGTERM, its graceful shutdown runs, and that stops
its Ray cluster and its inference process too. Before this, a pytest run killed by `timeout` left a server
and its Ray processes running for half an hour.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(sig: signal.Signals = signal.SIGTERM) -> bool:
    """Ask the kernel for `sig` when the parent process exits (Linux); False where that is unavailable.

    A parent that died before the request leaves the process to init (or a subreaper) already: then the
    signal is raised at once.
    """
    if not sys.platform.startswith("linux"):
        return False
    parent = os.getppid()
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    if parent == 1 or os.getppid() != parent:
        os.kill(os.getpid(), sig)
    return True
