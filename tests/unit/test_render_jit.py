"""The kernels' on-disk cache is keyed by every kernel source: Numba alone checks only the timestamp of the
file that defines a kernel, so an edit to a helper it inlines from another file would load stale code."""

from __future__ import annotations

import shutil
from pathlib import Path

import numba

from workers.render import jit


def test_any_kernel_source_change_moves_the_cache_and_other_files_do_not(tmp_path):
    package = tmp_path / "workers"
    shutil.copytree(jit.PACKAGE / "render", package / "render")
    (package / "render" / "notes.py").write_text('"""No kernels here."""\n')
    before = jit.kernel_sources_digest(package)

    (package / "render" / "notes.py").write_text('"""Still no kernels."""\n')
    assert jit.kernel_sources_digest(package) == before

    helpers = package / "render" / "kernels.py"  # inlined into the BSDF and wavefront kernels
    helpers.write_text(helpers.read_text().replace("INV_PI = 1.0 / math.pi", "INV_PI = 0.3183"))
    assert jit.kernel_sources_digest(package) != before


def test_the_project_kernels_compile_into_the_keyed_folder():
    from workers.render import kernels  # noqa: F401  (a kernel module: decorated after jit configured Numba)

    assert Path(numba.config.CACHE_DIR).name == jit.kernel_sources_digest()
