"""Every particle loop of the committed structure-of-arrays kernels, the map lookup and the SIR step (its loops
marked with a plain `#pragma omp simd`) vectorises with the flags the cache uses.

A loop left scalar runs several times slower per particle and no test of values notices: tan3dof's f and the
map lookup were scalar on AVX2 machines (no AVX-512) until -fno-trapping-math joined the SoA flags and the
lookup stopped converting doubles to 64-bit integers (benchmarks/README.md, bench_tan). gcc's own report
(-fopt-info-vec-optimized) is the check. Only with gcc on x86-64 with glibc: elsewhere sin/cos have no vector
variants (libmvec) and the model kernels' loops are scalar by design.
"""
from __future__ import annotations

import importlib
import os
import platform
import re
import subprocess
from pathlib import Path

import pytest

from abyssal.runtime.compiled.sources import C_DIR

build = importlib.import_module("abyssal.generated.build")  # (abyssal.generated.build is also a function's name)
GENERATED = Path(build.__file__).resolve().parent
MODEL_KERNELS = sorted(GENERATED.glob("*/*_soa.c"))
TERRAIN = C_DIR / "abyssal_sir_terrain_soa.c"
SIR_STEP = C_DIR / "abyssal_sir_soa.c"


@pytest.fixture(scope="module")
def gcc() -> str:
    if platform.machine() != "x86_64" or platform.libc_ver()[0] != "glibc":
        pytest.skip("skipped, because libmvec (glibc on x86-64) is what lets the kernels' sin/cos vectorise")
    try:
        cc = build.compiler()
        version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=10).stdout
    except (build.CompilerNotFoundError, OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"skipped, because no C compiler runs here ({exc})")
    if "Free Software Foundation" not in version:
        pytest.skip(f"skipped, because {cc} is not gcc (the check reads gcc's vectorisation report)")
    return cc


def scalar_loops(cc: str, path: Path, marker: str) -> list[int]:
    """Lines of the loop markers in `path` with no vectorised loop between them and the next marker."""
    flags = build._file_flags(path.name, build.cflags(), strict=path.parent == C_DIR)
    report = subprocess.run([cc, *flags, f"-I{path.parent}", "-fopt-info-vec-optimized", "-c", str(path), "-o",
                             os.devnull], capture_output=True, text=True, timeout=300, check=True).stderr
    vectorised = {int(m.group(1)) for m in re.finditer(rf"{re.escape(path.name)}:(\d+):\d+: optimized: loop vectorized",
                                                       report)}
    markers = [i + 1 for i, line in enumerate(path.read_text().splitlines()) if line.strip() == marker]
    assert markers, f"no {marker} in {path.name}"
    ends = [*markers[1:], 1 << 30]
    return [start for start, end in zip(markers, ends) if not any(start < line < end for line in vectorised)]


@pytest.mark.parametrize("path", MODEL_KERNELS, ids=lambda p: p.name)
def test_every_particle_loop_of_a_model_kernel_vectorises(gcc, path):
    assert scalar_loops(gcc, path, "ABYSSAL_SIMD_LOOP") == [], f"{path.name}: scalar particle loops"


def test_every_loop_of_the_map_lookup_vectorises(gcc):
    assert scalar_loops(gcc, TERRAIN, "#pragma omp simd") == [], f"{TERRAIN.name}: scalar loops"


def test_every_plain_particle_loop_of_the_sir_step_vectorises(gcc):
    # the step's own Box-Muller transform exists so that its normals loops vectorise without a vector logf/sinf/cosf
    assert scalar_loops(gcc, SIR_STEP, "#pragma omp simd") == [], f"{SIR_STEP.name}: scalar loops"
