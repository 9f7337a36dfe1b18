// exr.js — decodes the OpenEXR images the daemon sends into linear RGB floats: single-part
// scanline files with compression NONE, ZIPS or ZIP and HALF or FLOAT channels R, G, B (the
// daemon writes NONE FLOAT by default, ?compression=zip ZIP, ?pixel=half HALF). Anything else (tiles, deep data,
// several parts, other codecs, subsampled channels) is refused with a message rather than shown
// wrong. Written from the OpenEXR file layout; inflate is the browser's DecompressionStream.

const MAGIC = 20000630;
const FLAG_TILED = 0x200;
const FLAG_NON_IMAGE = 0x800;
const FLAG_MULTIPART = 0x1000;
const COMPRESSION_NAMES = ['NONE', 'RLE', 'ZIPS', 'ZIP', 'PIZ', 'PXR24', 'B44', 'B44A', 'DWAA', 'DWAB'];
const LINES_PER_CHUNK = { NONE: 1, ZIPS: 1, ZIP: 16 };
const PIXEL_TYPES = [
  { name: 'UINT', bytes: 4 },
  { name: 'HALF', bytes: 2 },
  { name: 'FLOAT', bytes: 4 },
];
const MAX_PIXELS = 64 * 1024 * 1024;

export class ExrError extends Error {}

class Reader {
  constructor(buffer) {
    this.view = new DataView(buffer);
    this.bytes = new Uint8Array(buffer);
    this.pos = 0;
  }

  need(n) {
    if (this.pos + n > this.bytes.length) throw new ExrError('the EXR file is truncated');
  }

  u8() {
    this.need(1);
    return this.bytes[this.pos++];
  }

  i32() {
    this.need(4);
    const v = this.view.getInt32(this.pos, true);
    this.pos += 4;
    return v;
  }

  u64() {
    this.need(8);
    const lo = this.view.getUint32(this.pos, true);
    const hi = this.view.getUint32(this.pos + 4, true);
    this.pos += 8;
    if (hi >= 1 << 21) throw new ExrError('an EXR chunk offset is out of range');
    return hi * 2 ** 32 + lo;
  }

  // A NUL-terminated name; the format allows 255 bytes with the long-names flag.
  cstring() {
    const start = this.pos;
    const end = this.bytes.indexOf(0, start);
    if (end < 0 || end - start > 255) throw new ExrError('the EXR header is malformed');
    this.pos = end + 1;
    return new TextDecoder().decode(this.bytes.subarray(start, end));
  }
}

function readChannels(r, end) {
  const channels = [];
  while (r.pos < end) {
    const name = r.cstring();
    if (name === '') break;
    const type = r.i32();
    r.pos += 4; // pLinear and three reserved bytes
    const xSampling = r.i32();
    const ySampling = r.i32();
    if (!PIXEL_TYPES[type]) throw new ExrError(`channel ${name} has an unknown pixel type ${type}`);
    if (xSampling !== 1 || ySampling !== 1) throw new ExrError(`channel ${name} is subsampled`);
    channels.push({ name, type: PIXEL_TYPES[type] });
  }
  return channels;
}

function readHeader(r) {
  if (r.i32() !== MAGIC) throw new ExrError('not an OpenEXR file');
  const flags = r.i32();
  if ((flags & 0xff) !== 2) throw new ExrError(`EXR version ${flags & 0xff} is not supported`);
  if (flags & (FLAG_TILED | FLAG_NON_IMAGE | FLAG_MULTIPART))
    throw new ExrError('tiled, deep and multi-part EXR files are not supported here');
  const header = {};
  for (;;) {
    const name = r.cstring();
    if (name === '') break;
    r.cstring(); // the attribute's type name: the attributes read here have fixed types
    const size = r.i32();
    const end = r.pos + size;
    r.need(size);
    if (name === 'channels') header.channels = readChannels(r, end);
    else if (name === 'compression') header.compression = COMPRESSION_NAMES[r.u8()] ?? 'unknown';
    else if (name === 'dataWindow') header.dataWindow = [r.i32(), r.i32(), r.i32(), r.i32()];
    r.pos = end;
  }
  if (!header.channels || !header.dataWindow || !header.compression)
    throw new ExrError('the EXR header lacks channels, compression or dataWindow');
  return header;
}

export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const exponent = (h >> 10) & 0x1f;
  const mantissa = h & 0x3ff;
  if (exponent === 0) return sign * mantissa * 2 ** -24;
  if (exponent === 31) return mantissa ? NaN : sign * Infinity;
  return sign * (1 + mantissa / 1024) * 2 ** (exponent - 15);
}

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// ZIP and ZIPS store the bytes predicted (each one minus its predecessor, plus 128) and split
// into even-indexed then odd-indexed halves; this undoes both.
function unpredict(t) {
  for (let i = 1; i < t.length; i++) t[i] = (t[i - 1] + t[i] - 128) & 0xff;
  const out = new Uint8Array(t.length);
  const half = (t.length + 1) >> 1;
  for (let k = 0, i = 0; k < half; k++) {
    out[i++] = t[k];
    if (i < t.length) out[i++] = t[half + k];
  }
  return out;
}

async function chunkBytes(packed, unpackedSize, compression) {
  // A chunk that would not shrink is stored as is, whatever the file's compression.
  if (compression === 'NONE' || packed.length >= unpackedSize) return packed;
  const raw = unpredict(await inflate(packed));
  if (raw.length !== unpackedSize) throw new ExrError('an EXR chunk inflates to the wrong size');
  return raw;
}

// Resolves to {width, height, rgb}: rgb is a Float32Array of width*height*3, top row first.
export async function decodeExr(buffer) {
  const r = new Reader(buffer);
  const header = readHeader(r);
  const linesPerChunk = LINES_PER_CHUNK[header.compression];
  if (!linesPerChunk) throw new ExrError(`EXR compression ${header.compression} is not supported here`);
  const [xMin, yMin, xMax, yMax] = header.dataWindow;
  const width = xMax - xMin + 1;
  const height = yMax - yMin + 1;
  if (width < 1 || height < 1 || width * height > MAX_PIXELS) throw new ExrError('bad EXR data window');
  const slots = ['R', 'G', 'B'].map((n) => header.channels.findIndex((c) => c.name === n));
  if (slots.includes(-1)) throw new ExrError('the EXR image has no R, G and B channels');

  const lineBytes = header.channels.reduce((sum, c) => sum + c.type.bytes * width, 0);
  const chunkCount = Math.ceil(height / linesPerChunk);
  const offsets = [];
  for (let i = 0; i < chunkCount; i++) offsets.push(r.u64());

  // Chunk headers are read first (the reader is sequential); the chunks then inflate at once.
  const chunks = offsets.map((offset) => {
    r.pos = offset;
    const y0 = r.i32() - yMin;
    const size = r.i32();
    if (y0 < 0 || y0 >= height || size < 0) throw new ExrError('an EXR chunk is out of the data window');
    r.need(size);
    return { y0, lines: Math.min(linesPerChunk, height - y0), packed: r.bytes.subarray(r.pos, r.pos + size) };
  });
  const rgb = new Float32Array(width * height * 3);
  await Promise.all(
    chunks.map(async ({ y0, lines, packed }) => {
      const data = await chunkBytes(packed, lines * lineBytes, header.compression);
      const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
      let at = 0;
      for (let line = 0; line < lines; line++) {
        const row = (y0 + line) * width;
        header.channels.forEach((channel, c) => {
          const slot = slots.indexOf(c);
          for (let x = 0; slot >= 0 && x < width; x++) {
            const p = at + x * channel.type.bytes;
            let v;
            if (channel.type.name === 'FLOAT') v = view.getFloat32(p, true);
            else if (channel.type.name === 'HALF') v = halfToFloat(view.getUint16(p, true));
            else v = view.getUint32(p, true);
            rgb[(row + x) * 3 + slot] = v;
          }
          at += width * channel.type.bytes;
        });
      }
    }),
  );
  return { width, height, rgb };
}
