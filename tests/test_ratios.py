"""bench/ratios.py (the report's "each reuse method against its baselines" table) on a made-up
error_vs_time.csv whose ratios are known: a baseline read log-log between its points, the
method's default setting in real time, its converge profile at pt's image times, and "—" where a
curve did not reach the time."""
import csv
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import ratios  # noqa: E402

FIELDS = ["scene", "regime", "method", "variant", "setting", "unit", "ms", "mape", "relmse", "rmse"]


def row(regime, method, setting, ms, err, variant=""):
    return {"scene": "s", "regime": regime, "method": method, "variant": variant, "setting": setting, "unit": "u",
            "ms": ms, "mape": err, "relmse": err * err, "rmse": err}


def test_ratios_read_the_baseline_at_the_methods_time(tmp_path):
    rows = [row("real-time", "pt", "1", 100, 1.0), row("real-time", "pt", "4", 400, 0.5),
            row("real-time", "restir_pt", "3", 200, 0.25), row("real-time", "restir_pt", "6", 300, 0.2),
            row("converge", "pt", "4", 400, 0.5), row("converge", "pt", "16", 1600, 0.25),
            row("converge", "restir_pt", "1", 400, 0.4, "converge profile"),
            row("converge", "restir_pt", "4", 1600, 0.1, "converge profile"),
            row("converge", "restir_pt", "1", 400, 9.0, "temporal reuse on")]
    with open(tmp_path / "error_vs_time.csv", "w", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        w.writeheader()
        w.writerows(rows)
    lines = ratios.table(tmp_path)
    # Real time: pt at 200 ms is sqrt(0.5) (halfway between 100 and 400 ms, log-log).
    rt = [ln for ln in lines if "real time" in ln]
    assert len(rt) == 1 and f"| {0.25 / math.sqrt(0.5):.2f} | {0.0625 / 0.5:.2f} |" in rt[0], rt
    assert "| 200 |" in rt[0] and "(3 u)" in rt[0]
    # Converge at pt's 4 and 16 spp: the converge profile's row, not the temporal one's; no 64.
    cv = [ln for ln in lines if "| converge |" in ln]
    assert len(cv) == 2, cv
    assert "| 0.80 | 0.64 | 0.80 |" in cv[0] and "| 0.40 | 0.16 | 0.40 |" in cv[1]
    # A time outside a curve: nothing read there.
    rows.append(row("converge", "pt", "64", 6400, 0.1))
    with open(tmp_path / "error_vs_time.csv", "w", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        w.writeheader()
        w.writerows(rows)
    assert "| — | — | — |" in ratios.table(tmp_path)[-1]
