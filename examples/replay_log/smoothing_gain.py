"""Smoothed against filtered on the simulated AUV of make_logs.py: RMSE and ANEES over many seeds.

    python smoothing_gain.py [--seeds 20] [--seconds 300] [--filters ekf ukf ckf]

Each seed simulates a dive (make_logs.simulate), writes it as CSV tables, and replays it with --smooth; the filtered
and the smoothed tracks are compared with the truth at every row's stamp (the stamps lie on the truth's 10 ms grid):
position RMSE (3-D), heading RMSE, and the ANEES (the NEES of the 7-state error, heading wrapped, averaged over the
rows and divided by 7: 1 for a consistent estimator). Printed as mean and [min, max] over the seeds.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def errors(track, rec) -> tuple[float, float, float]:
    k = np.searchsorted(rec.truth_ns, rec.truth_ns[0] + np.round(track.t * 1e9).astype(np.int64))
    truth = rec.truth[np.clip(k, 0, len(rec.truth) - 1)]
    e = track.x - truth
    e[:, 3] = np.angle(np.exp(1j * e[:, 3]))
    nees = np.einsum("ki,kij,kj->k", e, np.linalg.inv(track.P), e)
    return (float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))), float(np.sqrt(np.mean(e[:, 3] ** 2))),
            float(np.mean(nees) / e.shape[1]))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--filters", nargs="+", default=["ekf", "ukf", "ckf"])
    args = parser.parse_args(argv)
    import abyssal
    from abyssal.runtime.replay import replay

    sys.path.insert(0, str(HERE))
    import make_logs
    from auv import small_auv

    started = time.perf_counter()
    table: dict = {f: {"filtered": [], "smoothed": []} for f in args.filters}
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        vehicle = abyssal.load(abyssal.generate(small_auv(), work / "gen"))
        _, map_csv = make_logs.write_maps(work)
        for seed in range(args.seeds):
            rec = make_logs.simulate(seed, args.seconds)
            folder = make_logs.write_csv(rec, work / f"csv{seed}")
            for name in args.filters:
                result = replay(folder, vehicle, name, map_csv, smooth=True, progress=False)
                table[name]["filtered"].append(errors(result.track, rec))
                table[name]["smoothed"].append(errors(result.smoothed, rec))
    print(f"{args.seeds} seeds of {args.seconds:g} s (make_logs.simulate), replayed from CSV with --smooth; mean "
          f"[min, max] over the seeds; {time.perf_counter() - started:.0f} s")
    print(f"{'filter':8s} {'track':9s} {'position RMSE (m)':>26s} {'heading RMSE (mrad)':>26s} {'ANEES':>24s}")
    for name, rows in table.items():
        for kind in ("filtered", "smoothed"):
            values = np.array(rows[kind])
            cells = []
            for j, scale in enumerate((1.0, 1000.0, 1.0)):
                v = values[:, j] * scale
                cells.append(f"{v.mean():8.3f} [{v.min():6.3f}, {v.max():6.3f}]")
            print(f"{name.upper():8s} {kind:9s} {cells[0]:>26s} {cells[1]:>26s} {cells[2]:>24s}")
    return table


if __name__ == "__main__":
    main()
