"""bench/ratios.py — each reuse method against the baselines it exists to beat, at equal time,
read off a report's error_vs_time.csv (`make bench-report`, or a partial run's REPORT_OUT).

Real time: the method's frame at its default setting (the first value of its ladder) against
each baseline's real-time curve at that frame time. Converge: the method's converge-profile
curve against the baseline's converge curve at pt's image time at 64 spp (16 in QUICK runs), and
at 16 and 4 spp. Curves are read log-log between their measured points and never outside them
(bench/curves.py), so a budget a curve did not reach prints "—". A ratio below 1 means the
method's error is lower. Usage:

  /usr/bin/python3 bench/ratios.py docs/report
  /usr/bin/python3 bench/ratios.py build/try/reuse"""
import csv
import sys
from pathlib import Path

from curves import loglog_at
from regimes import LADDER

# method: the baselines the method is measured against (its papers' baselines here).
PAIRS = {"restir_pt": ["pt"], "restir_bdpt": ["restir_pt", "bdpt"], "restir_sss": ["pt"], "restir_sms": ["sms"]}
KEYS = ("mape", "relmse", "rmse")


def curve(rows, scene, regime, method, variant=""):
    return [r for r in rows if r["scene"] == scene and r["regime"] == regime and r["method"] == method
            and r["variant"] == variant]


def at(rs, ms, key):
    """A curve's error `key` at time ms (its rows, from the CSV or in memory), interpolated log-log
    inside its measured range (None outside)."""
    return loglog_at([(float(r["ms"]), float(r[key])) for r in rs], ms)


def fmt(x):
    return "—" if x is None else f"{x:.2f}"


def table(folder):
    """The table's lines (markdown) of a report folder's error_vs_time.csv."""
    rows = list(csv.DictReader(open(Path(folder) / "error_vs_time.csv")))
    scenes = sorted({r["scene"] for r in rows})
    out = ["| scene | regime | method | baseline | at ms | MAPE ratio | relMSE ratio | RMSE ratio |",
           "|---|---|---|---|---|---|---|---|"]
    for scene in scenes:
        for method, baselines in PAIRS.items():
            rt = curve(rows, scene, "real-time", method)
            default = [r for r in rt if r["setting"] == str(LADDER[method][1][0])]
            for b in baselines if default else []:
                base = curve(rows, scene, "real-time", b)
                if not base:
                    continue
                ms = float(default[0]["ms"])
                ratios = [None if at(base, ms, k) is None else float(default[0][k]) / at(base, ms, k) for k in KEYS]
                out.append(f"| {scene} | real time | {method} ({default[0]['setting']} {default[0]['unit']}) | {b} | "
                           f"{ms:.0f} | " + " | ".join(fmt(x) for x in ratios) + " |")
            cv = curve(rows, scene, "converge", method, "converge profile")
            pt_cv = {r["setting"]: float(r["ms"]) for r in curve(rows, scene, "converge", "pt")}
            for b in baselines:
                base = curve(rows, scene, "converge", b) or curve(rows, scene, "converge", b, "converge profile")
                if not (cv and base):
                    continue
                for spp in ("4", "16", "64"):
                    if spp not in pt_cv:
                        continue
                    ms = pt_cv[spp]
                    ratios = [None if at(cv, ms, k) is None or at(base, ms, k) is None else at(cv, ms, k) / at(base, ms, k)
                              for k in KEYS]
                    out.append(f"| {scene} | converge | {method} (converge profile) | {b} | {ms:.0f} (pt {spp} spp) | "
                               + " | ".join(fmt(x) for x in ratios) + " |")
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    print("\n".join(table(sys.argv[1])))
