// viewer.js — the HDR image view: linear RGB floats shown through an exposure (stops), a tone
// curve and the sRGB transfer function, zoomed by whole factors with square pixels, with the
// float values under the pointer; the default zoom, 'fit', is the largest whole factor at which
// the image fits the view's area (an image larger than the area: the largest 1/n, smoothed), kept
// as that area changes size. It shows image A,
// image B, a swipe (A left of the split, B right of it) or an 8-bit false-colour error map.
// The curves are those of the daemon's PNG previews (renderer/image/tonemap.c), so ?tonemap= and this
// view agree: clamp, Reinhard x/(1+x), and Narkowicz's ACES fit clipped at 1.

const CURVES = {
  clamp: (x) => Math.min(x, 1),
  reinhard: (x) => x / (1 + x),
  aces: (x) => Math.min((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 1),
};
const MAGENTA = [255, 0, 255]; // non-finite values, as the daemon's previews show them
const X_MAX = 1e9; // exposed values are clipped here first, as in tonemap.c

function srgb8(v) {
  const c = v <= 0 ? 0 : v >= 1 ? 1 : v;
  const e = c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055;
  return Math.round(255 * e);
}

export class HdrViewer {
  constructor(canvas, splitLine) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d', { willReadFrequently: true });
    this.splitLine = splitLine;
    this.a = null;
    this.b = null;
    this.errorMap = null;
    this.mode = 'a';
    this.exposure = 0;
    this.curve = 'clamp';
    this.zoom = 'fit';
    this.split = 0.5;
    this.draws = 0;
    // The area the image is fitted to is the canvas's scrolling box; a fitted image follows it
    // when the window (or the page's layout) resizes it.
    this.area = canvas.parentElement;
    new ResizeObserver(() => {
      if (this.zoom === 'fit') this.place();
    }).observe(this.area);
  }

  // The screen pixels per image pixel now: the chosen factor, or the fitted one. A fitted factor
  // is whole, as a chosen one is: with pixelated rendering a factor of 2.6 would show pixels as
  // blocks of 2 and 3. Below 1 it is 1/n, and the canvas is smoothed (see place()).
  scale() {
    if (this.zoom !== 'fit') return this.zoom;
    const { clientWidth, clientHeight } = this.area;
    const fit = Math.min(clientWidth / this.canvas.width, clientHeight / this.canvas.height);
    if (!Number.isFinite(fit) || fit <= 0) return 1;
    return fit >= 1 ? Math.floor(fit) : 1 / Math.ceil(1 / fit);
  }

  // Sizes the canvas and the split line on screen (the pixels stay as they are).
  place() {
    const scale = this.scale();
    // A fitted image is never scrolled: a scroll bar would shrink the area it was fitted to.
    this.area.dataset.fit = String(this.zoom === 'fit');
    const width = Math.floor(this.canvas.width * scale);
    const height = Math.floor(this.canvas.height * scale);
    this.canvas.style.width = `${width}px`;
    this.canvas.style.height = `${height}px`;
    this.canvas.dataset.scale = String(scale);
    // Below 1× a pixel cannot be a block, and pixelated rendering would drop all but one of each
    // n × n; smoothing blends them instead (style.css).
    this.canvas.dataset.smooth = String(scale < 1);
    this.splitLine.style.left = `${Math.round(this.split * this.canvas.width) * scale}px`;
    this.splitLine.style.height = `${height}px`;
  }

  set(changes) {
    Object.assign(this, changes);
    this.draw();
  }

  // What the canvas shows, as the mode allows with the images at hand.
  shown() {
    if (this.mode === 'error') return this.errorMap ? 'error' : 'none';
    if (this.mode === 'b') return this.b ? 'b' : 'none';
    if (this.mode === 'swipe' && this.a && this.b && this.a.width === this.b.width && this.a.height === this.b.height)
      return 'swipe';
    return this.a ? 'a' : 'none';
  }

  draw() {
    const shown = this.shown();
    const size = shown === 'error' ? this.errorMap : shown === 'b' ? this.b : this.a;
    const width = size ? size.width : 1;
    const height = size ? size.height : 1;
    if (this.canvas.width !== width || this.canvas.height !== height) {
      this.canvas.width = width;
      this.canvas.height = height;
    }
    if (shown === 'none') {
      this.ctx.clearRect(0, 0, width, height);
    } else if (shown === 'error') {
      this.ctx.drawImage(this.errorMap, 0, 0);
    } else {
      const splitX = shown === 'swipe' ? Math.round(this.split * width) : shown === 'b' ? 0 : width;
      this.ctx.putImageData(this.tonemap(this.a, this.b, splitX, shown === 'b' ? this.b : this.a), 0, 0);
    }
    this.splitLine.hidden = shown !== 'swipe';
    this.place();
    this.draws++;
    this.canvas.dataset.shown = shown;
    this.canvas.dataset.draws = String(this.draws);
  }

  // Pixels left of splitX come from `left`, the others from `right` (one of them may be unused).
  tonemap(left, right, splitX, base) {
    const { width, height } = base;
    const out = new ImageData(width, height);
    const gain = 2 ** this.exposure;
    const curve = CURVES[this.curve] || CURVES.clamp;
    for (let y = 0; y < height; y++) {
      for (let x = 0; x < width; x++) {
        const src = x < splitX ? left : right;
        const i = y * width + x;
        const o = i * 4;
        const r = src.rgb[i * 3];
        const g = src.rgb[i * 3 + 1];
        const b = src.rgb[i * 3 + 2];
        if (!Number.isFinite(r) || !Number.isFinite(g) || !Number.isFinite(b)) {
          [out.data[o], out.data[o + 1], out.data[o + 2]] = MAGENTA;
        } else {
          out.data[o] = srgb8(curve(Math.min(Math.max(r, 0) * gain, X_MAX)));
          out.data[o + 1] = srgb8(curve(Math.min(Math.max(g, 0) * gain, X_MAX)));
          out.data[o + 2] = srgb8(curve(Math.min(Math.max(b, 0) * gain, X_MAX)));
        }
        out.data[o + 3] = 255;
      }
    }
    return out;
  }

  // The image pixel under a pointer event, or null off the image.
  pixelAt(event) {
    const rect = this.canvas.getBoundingClientRect();
    const x = Math.floor(((event.clientX - rect.left) / rect.width) * this.canvas.width);
    const y = Math.floor(((event.clientY - rect.top) / rect.height) * this.canvas.height);
    if (x < 0 || y < 0 || x >= this.canvas.width || y >= this.canvas.height) return null;
    return { x, y };
  }

  static value(image, x, y) {
    if (!image || x >= image.width || y >= image.height) return null;
    const i = (y * image.width + x) * 3;
    return [image.rgb[i], image.rgb[i + 1], image.rgb[i + 2]];
  }
}
