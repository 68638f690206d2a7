"""The compute side of neuralbake: the scene format, the path tracer, the neural toolkit, the model kinds
and the runtime that trains them on Ray.

Importing it makes OpenMP's idle threads wait passively (unless the environment already says how). The
setting must be made before torch loads its OpenMP runtime, and every entry point (the services, the
command line, Ray's workers, the tests and benches) imports this package first. OpenMP's default active
wait spins each idle thread of torch's pool at every parallel region; when the 2-core machine runs anything
else, a spinning thread holds the core its partner needs: with one other busy process, a quick-preset lod
training step took 0.71 s on two threads with active waiting, 0.012 s with passive waiting and 0.020 s on
one thread; a default-preset prt job spent 88% of its CPU in a spinning idle thread and had not finished
4000 steps after 12 CPU minutes, against 175 CPU s with passive waiting (prt12b).

A program that loads torch before this package keeps the active wait (OpenMP reads the policy once), and
is warned: a script that did so spent 16-24 ms of CPU per hash-grid step of 128 points against 0.3 ms.
"""

import os
import sys
import warnings

if "torch" in sys.modules and "OMP_WAIT_POLICY" not in os.environ:
    warnings.warn(
        "torch was imported before workers, so OpenMP's idle threads spin (OMP_WAIT_POLICY is read once, "
        "when torch loads): import workers first, or set OMP_WAIT_POLICY=PASSIVE in the environment",
        RuntimeWarning,
        stacklevel=2,
    )
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
