"""The hand-written C runtime (runtime/c) as the compile cache and `abyssal export` take it: file name -> text.

    kalman = build("abyssal_kalman", sources(KALMAN), strict=True)

Two libraries, each compiled once per machine through the cache of abyssal.generated.build: the Kalman family
(KALMAN) and the SIR step of the particle filters (SIR). Neither holds a model: a Kalman filter reaches its model
through the descriptor ``<m>_descriptor`` compiled into the model's own library, the SIR step through the
pointers of the model's kernels it is given. The descriptor's type, abyssal_model.h, is the interface the code
generator writes to, so it lives beside the generator (abyssal.symbolic.codegen.MODEL_HEADER).
"""
from __future__ import annotations

from pathlib import Path

from abyssal.symbolic.codegen import MODEL_HEADER

#: the folder of the hand-written C runtime (C99, compiled with -Wall -Wextra -Werror -pedantic)
C_DIR = Path(__file__).resolve().parent.parent / "c"
#: the Kalman family: the filter object (its transaction, sensors, time and history, smoothing), the algebra of
#: every step (abyssal_kalman_steps), the dense linear algebra, the gate, covariance checks and repair, and the
#: CasADi-convention entry points Python binds (abyssal_kalman_binding.c: not shipped by `abyssal export`)
KALMAN = ("abyssal_kalman.h", "abyssal_kalman.c", "abyssal_kalman_steps.h", "abyssal_kalman_steps.c", "abyssal_linalg.h",
          "abyssal_linalg.c", "abyssal_kalman_gate.h", "abyssal_kalman_gate.c", "abyssal_kalman_covariance.h",
          "abyssal_kalman_covariance.c", "abyssal_kalman_binding.c")
#: the SIR step (its *_soa.c files compile with the structure-of-arrays flags)
SIR = ("abyssal_rng.h", "abyssal_sir.h", "abyssal_sir_soa.c", "abyssal_sir_terrain.h", "abyssal_sir_terrain_soa.c")
#: the templates of an exported project (CMakeLists.txt.in, run_csv.c, the tests)
EXPORT_TEMPLATES = C_DIR / "export"


def sources(names) -> dict[str, str]:
    """File name -> text of the named runtime files; the Kalman family's with the model interface abyssal_model.h."""
    texts = {name: (C_DIR / name).read_text() for name in names}
    if any(name.startswith("abyssal_kalman") for name in names):
        texts[MODEL_HEADER.name] = MODEL_HEADER.read_text()
    return texts


__all__ = ["C_DIR", "EXPORT_TEMPLATES", "KALMAN", "SIR", "sources"]
