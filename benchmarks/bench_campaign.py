"""Bench section: campaign throughput (runs per minute) of the ROV experiment on 1 and 2 Dask workers.

The same campaign (``experiments.rov.experiment``: every filter of `abyssal reproduce rov` in every
case) runs in this process (``workers=0``, the peer without Dask), on a local cluster of one worker
process and on one of two; each is timed end to end, cluster start-up included. The scenario is
shortened (``duration`` below, stated in the results; the EM-MOGCPF N sweep at 2N instead of 1000
and 3000) so the section stays short; a run of the full 200 s scenario costs about 200 s / duration
times more, plus the larger sweep. The 2-worker table must equal the
1-worker one (checked here too). Target: 2 workers at least 1.5x the runs per minute of 1 (2 cores).
"""
from __future__ import annotations

import time


def run(quick: bool = False, verbose: bool = True) -> dict:
    from abyssal.runtime.experiments import campaign
    from abyssal.runtime.experiments.rov import experiment
    from bench import target

    duration, n_particles, runs = (2.0, 30, 2) if quick else (10.0, 300, 4)
    config = experiment.short_config(duration=duration, n_particles=n_particles)
    results: dict[str, dict] = {}
    tables = {}
    for label, workers in (("in-process", 0), ("1 worker", 1), ("2 workers", 2)):
        t0 = time.perf_counter()
        result = campaign.run_campaign(experiment.run_one, config, runs, seed=0, workers=workers,
                                       experiment="bench", extra_columns=experiment.EXTRA_COLUMNS, progress=False)
        seconds = time.perf_counter() - t0
        if not result.ok:
            raise RuntimeError(f"bench campaign failed: {campaign.summarise_failures(result)}")
        tables[label] = experiment.report(result.rows)
        results[label] = {"runs": runs, "seconds": seconds, "runs_per_minute": 60.0 * runs / seconds}
        if verbose:
            print(f"  {label:<11} {runs} runs in {seconds:6.1f} s: {60 * runs / seconds:7.1f} runs/min", flush=True)
    speedup = results["2 workers"]["runs_per_minute"] / results["1 worker"]["runs_per_minute"]
    identical = tables["1 worker"] == tables["2 workers"] == tables["in-process"]
    if verbose:
        print(f"  2 workers / 1 worker: {speedup:.2f}x; tables identical: {identical}", flush=True)
    return {"results": {"throughput": results, "speedup_2_over_1": speedup, "tables_identical": identical,
                        "scenario": f"rov, seed 000, every filter and case, T = {duration} s, N = {n_particles}"},
            "targets": [target("campaign speed-up, 2 workers over 1", speedup, 1.5, "x", higher_is_better=True),
                        target("1- and 2-worker tables identical", float(identical), 1.0, "", higher_is_better=True)]}
