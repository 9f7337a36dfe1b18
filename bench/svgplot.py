"""bench/svgplot.py — log-log line charts as standalone SVG (the benchmarks' charts; no plotting
library is needed). One function: loglog(path, title, xlabel, ylabel, series), where series is a
list of (label, [(x, y), ...], style) and style is "line" or "points"."""
import math

COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"]
W, H = 760, 420
LEFT, RIGHT, TOP, BOTTOM = 70, 290, 40, 55


def _decades(lo, hi):
    """Tick values: 1, 2, 5 times powers of ten inside [lo, hi]."""
    ticks = []
    for e in range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1):
        for m in (1, 2, 5):
            v = m * 10.0**e
            if lo <= v <= hi:
                ticks.append(v)
    return ticks


def _fmt(v):
    return f"{v:g}" if 1e-3 <= v < 1e5 else f"{v:.0e}"


def loglog(path, title, xlabel, ylabel, series):
    pts = [p for _, data, _ in series for p in data if p[0] > 0 and p[1] > 0]
    if not pts:
        raise ValueError("nothing to plot")
    x0, x1 = min(p[0] for p in pts), max(p[0] for p in pts)
    y0, y1 = min(p[1] for p in pts), max(p[1] for p in pts)
    # Pad by a tenth of a decade on each side so points do not sit on the frame.
    x0, x1 = x0 / 10**0.1, x1 * 10**0.1
    y0, y1 = y0 / 10**0.1, y1 * 10**0.1
    pw, ph = W - LEFT - RIGHT, H - TOP - BOTTOM

    def X(v):
        return LEFT + pw * (math.log10(v) - math.log10(x0)) / (math.log10(x1) - math.log10(x0))

    def Y(v):
        return TOP + ph * (1 - (math.log10(v) - math.log10(y0)) / (math.log10(y1) - math.log10(y0)))

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>',
           f'<text x="{LEFT + pw / 2}" y="22" text-anchor="middle" font-size="14">{title}</text>',
           f'<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="#333"/>']
    for v in _decades(x0, x1):
        out.append(f'<line x1="{X(v):.1f}" y1="{TOP}" x2="{X(v):.1f}" y2="{TOP + ph}" stroke="#ddd"/>')
        out.append(f'<text x="{X(v):.1f}" y="{TOP + ph + 16}" text-anchor="middle">{_fmt(v)}</text>')
    for v in _decades(y0, y1):
        out.append(f'<line x1="{LEFT}" y1="{Y(v):.1f}" x2="{LEFT + pw}" y2="{Y(v):.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{LEFT - 6}" y="{Y(v) + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
    out.append(f'<text x="{LEFT + pw / 2}" y="{H - 14}" text-anchor="middle">{xlabel}</text>')
    out.append(f'<text transform="translate(16 {TOP + ph / 2}) rotate(-90)" text-anchor="middle">{ylabel}</text>')
    for i, (label, data, style) in enumerate(series):
        color = COLORS[i % len(COLORS)]
        data = [p for p in data if p[0] > 0 and p[1] > 0]
        if style == "line" and len(data) > 1:
            d = " ".join(f"{'M' if j == 0 else 'L'}{X(x):.1f},{Y(y):.1f}" for j, (x, y) in enumerate(data))
            out.append(f'<path d="{d}" fill="none" stroke="{color}" stroke-width="2"/>')
        for x, y in data:
            out.append(f'<circle cx="{X(x):.1f}" cy="{Y(y):.1f}" r="3.5" fill="{color}"/>')
        ly = TOP + 14 + 18 * i
        out.append(f'<circle cx="{LEFT + pw + 16}" cy="{ly - 4}" r="4" fill="{color}"/>')
        out.append(f'<text x="{LEFT + pw + 26}" y="{ly}">{label}</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")
