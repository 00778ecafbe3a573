"""The replay's report: per sensor what the filter did with its samples, and whether its NIS fits the chi-square law.

Consistency (Bar-Shalom, Li and Kirubarajan 2001, section 5.4): the NIS of a consistent filter's update with d
entries is chi-square with d degrees of freedom. Over the K used updates of a sensor with D entries in all, K times
the mean NIS is chi-square with D degrees of freedom, so the mean lies in [chi2.ppf(0.025, D) / K,
chi2.ppf(0.975, D) / K] with probability 0.95; above: the filter is overconfident for that sensor (R or Q too small,
or a model error), below: too cautious. Each update's NIS is also compared with its own 95 % interval: about 5 % of
them fall outside when the filter is consistent.
"""
from __future__ import annotations

import json

import numpy as np
from scipy.stats import chi2

from .run import Replay

PROBABILITY = 0.95


def nis_check(replay: Replay, sensor: str) -> dict:
    """The NIS statistics of one sensor (module docstring); NaN entries when it had no used update (or a PF)."""
    used = [m for m in replay.measurements if m.sensor == sensor and m.nis_dof > 0 and np.isfinite(m.nis)]
    out = {"updates": len(used), "mean": float("nan"), "bounds": [float("nan"), float("nan")],
           "outside": float("nan"), "verdict": "no NIS (no update used it)" if replay.filter_name != "PF" else
           "no NIS (not defined for a particle filter)"}
    if not used:
        return out
    nis = np.array([m.nis for m in used])
    dof = np.array([m.nis_dof for m in used])
    K, D = len(used), int(dof.sum())
    tail = (1 - PROBABILITY) / 2
    lower, upper = chi2.ppf(tail, D) / K, chi2.ppf(1 - tail, D) / K
    low_each, high_each = chi2.ppf(tail, dof), chi2.ppf(1 - tail, dof)
    mean = float(nis.mean())
    verdict = "consistent" if lower <= mean <= upper else (
        "NIS too large: overconfident (R or Q too small, or a model error)" if mean > upper else
        "NIS too small: too cautious (R or Q too large)")
    out.update(mean=mean, bounds=[float(lower), float(upper)], dof=D,
               outside=float(np.mean((nis < low_each) | (nis > high_each))), verdict=verdict)
    return out


def summary(replay: Replay) -> dict:
    """Everything the report says, as plain data (report.json)."""
    model, log, smap = replay.model, replay.log, replay.sensor_map
    sensors = {}
    for name, counts in replay.counts.items():
        sensors[name] = {"source": smap.sensors[name].source, **counts, "nis": nis_check(replay, name),
                         "covariance": {"model": "the filter's R", "message": "each message's own",
                                        "columns": "each row's std columns"}[smap.sensors[name].covariance]}
    track = replay.track
    result = {
        "log": str(log.path), "log_kind": log.kind, "model": model.name, "filter": replay.filter_name,
        "t0": replay.t0 + log.epoch, "duration_s": float(track.t[-1]) if track.t.size else 0.0,
        "events": len(track.t), "elapsed_s": replay.elapsed, "origin": log.origin,
        "states": list(model.state_names), "x_final": track.x[-1].tolist(),
        "std_final": np.sqrt(np.diag(track.P[-1])).tolist(), "sensors": sensors, "notes": list(replay.notes),
        "smoothed": replay.smoothed is not None,
    }
    if replay.smoothed is not None:
        result["x_smoothed_start"] = replay.smoothed.x[0].tolist()
        result["std_smoothed_start"] = np.sqrt(np.diag(replay.smoothed.P[0])).tolist()
    if smap.input is not None:
        result["input"] = {"source": smap.input.source, "samples": int(len(log.samples["input"].t))}
    return result


def _number(value, digits: int = 3) -> str:
    return "-" if value is None or (isinstance(value, float) and not np.isfinite(value)) else f"{value:.{digits}g}"


def markdown(data: dict) -> str:
    """report.md: the short report a reviewer reads first."""
    lines = [f"# abyssal replay: {data['log']}", "",
             f"Model `{data['model']}`, filter {data['filter']}{' with RTS smoothing' if data['smoothed'] else ''}; "
             f"{data['log_kind']} log; t0 = {data['t0']!r} s (log time); {data['duration_s']:.6g} s, {data['events']} "
             f"filter events in {data['elapsed_s']:.3g} s."]
    if data.get("origin") is not None:
        lat, lon, alt = data["origin"]
        lines.append(f"Local NED origin of the geodetic fixes: latitude {lat!r}, longitude {lon!r}, altitude {alt!r} m.")
    if "input" in data:
        lines.append(f"Input: {data['input']['source']}, {data['input']['samples']} samples (held between stamps).")
    lines += ["", "## Sensors", "",
              "| sensor | source | received | used | gated entries | P inflated | late (fused at stamp) | too late | skipped | "
              "R | NIS mean | 95 % bounds of the mean | outside own 95 % | verdict |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in data["sensors"].items():
        skipped = ", ".join(f"{count} {reason}" for reason, count in s["skipped"].items()) or "0"
        nis = s["nis"]
        bounds = "-" if not np.isfinite(nis["bounds"][0]) else f"[{nis['bounds'][0]:.3g}, {nis['bounds'][1]:.3g}]"
        outside = "-" if not np.isfinite(nis["outside"]) else f"{100 * nis['outside']:.1f} %"
        lines.append(f"| {name} | {s['source']} | {s['received']} | {s['used']} | {s['gated']} | {s['inflations']} | "
                     f"{s['late']} | {s['too late']} | {skipped} | {s['covariance']} | {_number(nis['mean'])} | {bounds} | {outside} | "
                     f"{nis['verdict']} |")
    lines += ["", "## Final state", "", "| state | filtered | 1 sigma |" + (" smoothed at t0 | 1 sigma |"
                                                                          if data["smoothed"] else ""),
              "|---|---|---|" + ("---|---|" if data["smoothed"] else "")]
    for i, name in enumerate(data["states"]):
        row = f"| {name} | {_number(data['x_final'][i], 6)} | {_number(data['std_final'][i])} |"
        if data["smoothed"]:
            row += f" {_number(data['x_smoothed_start'][i], 6)} | {_number(data['std_smoothed_start'][i])} |"
        lines.append(row)
    if data["notes"]:
        lines += ["", "## Notes", ""] + [f"- {note}" for note in data["notes"]]
    return "\n".join(lines) + "\n"


def write_report(replay: Replay, folder) -> dict:
    """report.json and report.md into folder; returns the data."""
    data = summary(replay)
    (folder / "report.json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    (folder / "report.md").write_text(markdown(data))
    return data
