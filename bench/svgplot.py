"""bench/svgplot.py — charts as standalone SVG (the benchmarks' charts; no plotting library is
needed). chart(path, title, xlabel, ylabel, series, xlog, ylog) draws lines and points, where
series is a list of (label, [(x, y), ...], style[, colour]): style is "line", "dashed", "points" or
"squares" (open squares: single measurements beside the curves),
colour an index into COLORS (default: the series' own index); loglog() is
chart() with both axes logarithmic; stacked_bars(path, title, ylabel, bars, parts) draws one bar
per (label, {part: value}) with its parts stacked."""
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


def _linear_ticks(lo, hi):
    """About six round ticks inside [lo, hi]."""
    step = 10.0 ** math.floor(math.log10((hi - lo) / 5.0)) if hi > lo else 1.0
    for m in (1, 2, 5, 10):
        if (hi - lo) / (m * step) <= 7:
            step *= m
            break
    v, ticks = math.ceil(lo / step) * step, []
    while v <= hi + 1e-12:
        ticks.append(round(v, 12))
        v += step
    return ticks


def _axis(lo, hi, log, start, length, flip):
    """Padded range, a value -> pixel map and the ticks of one axis."""
    if log:
        lo, hi = lo / 10**0.1, hi * 10**0.1  # a tenth of a decade: points stay off the frame
        f = lambda v: (math.log10(v) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
        ticks = _decades(lo, hi)
    else:
        pad = 0.05 * (hi - lo) if hi > lo else 1.0
        lo, hi = lo - pad, hi + pad
        f = lambda v: (v - lo) / (hi - lo)
        ticks = _linear_ticks(lo, hi)
    return (lambda v: start + length * ((1 - f(v)) if flip else f(v))), ticks


def loglog(path, title, xlabel, ylabel, series):
    chart(path, title, xlabel, ylabel, series, xlog=True, ylog=True)


def chart(path, title, xlabel, ylabel, series, xlog=True, ylog=True):
    ok = lambda p: (p[0] > 0 or not xlog) and (p[1] > 0 or not ylog) and all(map(math.isfinite, p))
    pts = [p for s in series for p in s[1] if ok(p)]
    if not pts:
        raise ValueError("nothing to plot")
    pw, ph = W - LEFT - RIGHT, H - TOP - BOTTOM
    X, xticks = _axis(min(p[0] for p in pts), max(p[0] for p in pts), xlog, LEFT, pw, False)
    Y, yticks = _axis(min(p[1] for p in pts), max(p[1] for p in pts), ylog, TOP, ph, True)

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>',
           f'<text x="{W / 2}" y="22" text-anchor="middle" font-size="14">{title}</text>',
           f'<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="#333"/>']
    for v in xticks:
        out.append(f'<line x1="{X(v):.1f}" y1="{TOP}" x2="{X(v):.1f}" y2="{TOP + ph}" stroke="#ddd"/>')
        out.append(f'<text x="{X(v):.1f}" y="{TOP + ph + 16}" text-anchor="middle">{_fmt(v)}</text>')
    for v in yticks:
        out.append(f'<line x1="{LEFT}" y1="{Y(v):.1f}" x2="{LEFT + pw}" y2="{Y(v):.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{LEFT - 6}" y="{Y(v) + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
    out.append(f'<text x="{LEFT + pw / 2}" y="{H - 14}" text-anchor="middle">{xlabel}</text>')
    out.append(f'<text transform="translate(16 {TOP + ph / 2}) rotate(-90)" text-anchor="middle">{ylabel}</text>')
    for i, (label, data, style, *colour) in enumerate(series):
        color = COLORS[(colour[0] if colour else i) % len(COLORS)]
        data = [p for p in data if ok(p)]
        if style in ("line", "dashed") and len(data) > 1:
            d = " ".join(f"{'M' if j == 0 else 'L'}{X(x):.1f},{Y(y):.1f}" for j, (x, y) in enumerate(data))
            dash = ' stroke-dasharray="6 4"' if style == "dashed" else ""
            out.append(f'<path d="{d}" fill="none" stroke="{color}" stroke-width="2"{dash}/>')
        for x, y in data:
            if style == "squares":
                out.append(f'<rect x="{X(x) - 5:.1f}" y="{Y(y) - 5:.1f}" width="10" height="10" fill="none" '
                           f'stroke="{color}" stroke-width="2"/>')
            else:
                out.append(f'<circle cx="{X(x):.1f}" cy="{Y(y):.1f}" r="3.5" fill="{color}"/>')
        mark = f'<circle cx="{LEFT + pw + 16}" cy="{{y}}" r="4" fill="{color}"/>'
        if style == "squares":
            mark = (f'<rect x="{LEFT + pw + 11}" y="{{y_5}}" width="10" height="10" fill="none" stroke="{color}" '
                    f'stroke-width="2"/>')
        if style == "dashed":
            mark += (f'<line x1="{LEFT + pw + 6}" y1="{{y}}" x2="{LEFT + pw + 24}" y2="{{y}}" stroke="{color}" '
                     f'stroke-width="2" stroke-dasharray="4 2"/>')
        _legend(out, i, label, mark, -4, pw)
    _save(path, out)


def _legend(out, i, label, mark, dy, pw):
    """Legend entry i: `mark` with {y} (and {y_5}, 5 above it) filled in, then the label."""
    ly = TOP + 14 + 18 * i
    out.append(mark.format(y=ly + dy, y_5=ly + dy - 5))
    out.append(f'<text x="{LEFT + pw + 26}" y="{ly}">{label}</text>')


def _save(path, out):
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def stacked_bars(path, title, ylabel, bars, parts):
    """bars: [(label, {part: value})]; parts: the stacking order (legend)."""
    top = max((sum(v.get(p, 0.0) for p in parts) for _, v in bars), default=0.0)
    if not bars or not top > 0:
        raise ValueError("nothing to plot")
    pw, ph = W - LEFT - RIGHT, H - TOP - BOTTOM
    Y, yticks = _axis(0.0, top, False, TOP, ph, True)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>',
           f'<text x="{W / 2}" y="22" text-anchor="middle" font-size="14">{title}</text>',
           f'<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="#333"/>']
    for v in yticks:
        if v < 0:
            continue
        out.append(f'<line x1="{LEFT}" y1="{Y(v):.1f}" x2="{LEFT + pw}" y2="{Y(v):.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{LEFT - 6}" y="{Y(v) + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
    out.append(f'<text transform="translate(16 {TOP + ph / 2}) rotate(-90)" text-anchor="middle">{ylabel}</text>')
    slot = pw / len(bars)
    for i, (label, values) in enumerate(bars):
        x, base = LEFT + slot * (i + 0.2), 0.0
        for j, part in enumerate(parts):
            v = values.get(part, 0.0)
            if v > 0:
                out.append(f'<rect x="{x:.1f}" y="{Y(base + v):.1f}" width="{slot * 0.6:.1f}" '
                           f'height="{Y(base) - Y(base + v):.1f}" fill="{COLORS[j % len(COLORS)]}"/>')
            base += v
        out.append(f'<text x="{x + slot * 0.3:.1f}" y="{TOP + ph + 16}" text-anchor="middle">{label}</text>')
    for j, part in enumerate(parts):
        _legend(out, j, part, f'<rect x="{LEFT + pw + 12}" y="{{y}}" width="9" height="9" fill="{COLORS[j % len(COLORS)]}"/>', -9, pw)
    _save(path, out)
