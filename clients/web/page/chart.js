// chart.js — the live error-vs-time chart: per session, the MAPE of each frame against the
// chosen reference over the session's accumulated render time, both axes logarithmic (the way
// equal-time comparisons of renderers are read). The newest point is also written on the chart
// element (data-last-mape, data-last-time-s, data-last-frame, data-last-session), so the value
// can be read without looking at pixels.
import uPlot from './uPlot.esm.js';

const COLOURS = ['#2f6fdf', '#d9480f', '#2b8a3e', '#862e9c', '#c92a2a', '#0b7285'];
const HEIGHT = 240;

export class MapeChart {
  constructor(element) {
    this.element = element;
    this.series = new Map(); // session id -> {label, colour, times: [], mapes: []}
    this.plot = null;
    this.plotKeys = '';
    this.pending = false;
    new ResizeObserver(() => this.plot?.setSize(this.size())).observe(element);
  }

  size() {
    return { width: Math.max(200, this.element.clientWidth), height: HEIGHT };
  }

  add(id, label, timeS, mape, frame) {
    if (!(timeS > 0) || !(mape > 0)) return; // a log axis has no place for zero
    let s = this.series.get(id);
    if (!s) {
      s = { label, colour: COLOURS[this.series.size % COLOURS.length], times: [], mapes: [] };
      this.series.set(id, s);
    }
    s.times.push(timeS);
    s.mapes.push(mape);
    Object.assign(this.element.dataset, {
      lastMape: String(mape),
      lastTimeS: String(timeS),
      lastFrame: String(frame),
      lastSession: id,
      points: String([...this.series.values()].reduce((n, v) => n + v.times.length, 0)),
    });
    this.schedule();
  }

  clear(id) {
    if (this.series.delete(id)) this.schedule();
  }

  // One redraw per animation frame however many points arrive.
  schedule() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.redraw();
    });
  }

  redraw() {
    const entries = [...this.series.entries()];
    const keys = entries.map(([id]) => id).join(',');
    if (entries.length === 0) {
      this.plot?.destroy();
      this.plot = null;
      this.plotKeys = '';
      return;
    }
    const data = uPlot.join(entries.map(([, s]) => [s.times, s.mapes]));
    if (this.plot && keys === this.plotKeys) {
      this.plot.setData(data);
      return;
    }
    this.plot?.destroy();
    this.plotKeys = keys;
    this.plot = new uPlot(
      {
        ...this.size(),
        scales: { x: { time: false, distr: 3 }, y: { distr: 3 } },
        axes: [{ label: 'render time (s)' }, { label: 'MAPE' }],
        series: [
          { label: 'time (s)', value: (u, v) => (v == null ? '–' : v.toPrecision(3)) },
          ...entries.map(([, s]) => ({
            label: s.label,
            stroke: s.colour,
            width: 1.5,
            spanGaps: true,
            points: { show: true, size: 4 },
            value: (u, v) => (v == null ? '–' : v.toPrecision(4)),
          })),
        ],
      },
      data,
      this.element,
    );
  }
}
