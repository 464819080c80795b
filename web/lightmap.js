// The page's light-map mirror (web/livebake.js): the viewer's sparse page pyramid in WebGL 2
// textures, the twin of src/gpu/lightmap.rs. A pool texture of 16×16-texel pages, a page table
// per layer and LOD and a shown LOD per cell and layer, as integer textures; each socket
// update (docs/SERVE.md) writes exactly the pages, table entries and cell LODs it carries.

import { POOL_COLUMNS, TABLE_W } from "./shaders.js";

const PAGE_SIDE = 16;
const PAGE_FLOATS = PAGE_SIDE * PAGE_SIDE * 4;
const NO_PAGE = 0xffffffff;
const MAX_LODS = 8;
const UPDATE_HEADER = 32;

// Integer texture of TABLE_W columns holding `count` u32 entries; rows uploaded when dirty.
class IntTable {
  constructor(gl, count, fill) {
    this.gl = gl;
    this.rows = Math.max(1, Math.ceil(count / TABLE_W));
    this.data = new Uint32Array(this.rows * TABLE_W).fill(fill);
    this.tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.tex);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.R32UI, TABLE_W, this.rows, 0, gl.RED_INTEGER, gl.UNSIGNED_INT, this.data);
    this.lo = Infinity;
    this.hi = -1;
  }
  set(i, v) {
    if (this.data[i] === v) return;
    this.data[i] = v;
    const r = (i / TABLE_W) | 0;
    if (r < this.lo) this.lo = r;
    if (r > this.hi) this.hi = r;
  }
  upload() {
    if (this.hi < 0) return;
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.tex);
    const view = this.data.subarray(this.lo * TABLE_W, (this.hi + 1) * TABLE_W);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, this.lo, TABLE_W, this.hi - this.lo + 1, gl.RED_INTEGER, gl.UNSIGNED_INT, view);
    this.lo = Infinity;
    this.hi = -1;
  }
  dispose() { this.gl.deleteTexture(this.tex); }
}

export class LightMap {
  constructor(gl, scene) {
    this.gl = gl;
    this.scene = scene;
    const cells = scene.grid.dims[0] * scene.grid.dims[1] * scene.grid.dims[2];
    this.cellCount = cells;
    // Per layer, per LOD: pages_x, pages_y, offset.
    this.levels = new Uint32Array(16 * 4);
    let offset = 0;
    for (let layer = 0; layer < 2; layer++)
      for (let k = 0; k < scene.lods; k++) {
        const [px, py] = scene.page_tables[k];
        this.levels.set([px, py, offset, 0], (layer * MAX_LODS + k) * 4);
        offset += px * py;
      }
    this.table = new IntTable(gl, offset, NO_PAGE);
    this.cells = new IntTable(gl, 2 * cells, 0);
    this.free = [];
    // Pages each layer holds: no punctual page, the one-layer program (fragmentShader).
    this.layerPages = [0, 0];
    this.capacityRows = 0;
    this.used = 0;
    this.poolData = new Float32Array(0);
    this.pool = null;
    this.grow(16);
    this.uploadPool();
    // Per pool row of pages, the columns written since the last upload.
    this.dirty = new Map();
    this.uploadCalls = 0;
  }
  // The pool holds POOL_COLUMNS × rows pages (its mirror here); growing makes a new texture,
  // which uploadPool() fills with the whole mirror.
  grow(rows) {
    const data = new Float32Array(POOL_COLUMNS * PAGE_SIDE * rows * PAGE_SIDE * 4);
    data.set(this.poolData);
    for (let s = POOL_COLUMNS * rows - 1; s >= POOL_COLUMNS * this.capacityRows; s--) this.free.push(s);
    this.poolData = data;
    this.capacityRows = rows;
    this.regrown = true;
  }
  uploadPool() {
    const gl = this.gl;
    if (this.pool) gl.deleteTexture(this.pool);
    this.pool = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.pool);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, POOL_COLUMNS * PAGE_SIDE, this.capacityRows * PAGE_SIDE, 0, gl.RGBA, gl.FLOAT, this.poolData);
    this.regrown = false;
    return this.poolData.length * 4;
  }
  // Uploads the written pages: one texSubImage2D per run of adjacent pages of a pool row
  // (new pages take consecutive free slots, so a publish's new pages are a few runs; a
  // rewritten page lies where it was), exactly the pages written; the whole pool after a
  // growth. Returns the bytes handed to the GL.
  uploadDirty() {
    const gl = this.gl;
    let bytes = 0;
    if (this.regrown) {
      bytes = this.uploadPool();
      this.uploadCalls++;
    }
    else if (this.dirty.size > 0) {
      const width = POOL_COLUMNS * PAGE_SIDE;
      gl.bindTexture(gl.TEXTURE_2D, this.pool);
      gl.pixelStorei(gl.UNPACK_ROW_LENGTH, width);
      for (const [row, set] of this.dirty) {
        const columns = [...set].sort((a, b) => a - b);
        for (let i = 0; i < columns.length;) {
          let j = i + 1;
          while (j < columns.length && columns[j] === columns[j - 1] + 1) j++;
          const lo = columns[i], w = (j - i) * PAGE_SIDE;
          gl.texSubImage2D(gl.TEXTURE_2D, 0, lo * PAGE_SIDE, row * PAGE_SIDE, w, PAGE_SIDE, gl.RGBA, gl.FLOAT,
            this.poolData, (row * PAGE_SIDE * width + lo * PAGE_SIDE) * 4);
          bytes += w * PAGE_SIDE * 16;
          this.uploadCalls++;
          i = j;
        }
      }
      gl.pixelStorei(gl.UNPACK_ROW_LENGTH, 0);
    }
    this.dirty.clear();
    return bytes;
  }
  entry(layer, lod, px, py) {
    return this.levels[(layer * MAX_LODS + lod) * 4 + 2] + py * this.levels[(layer * MAX_LODS + lod) * 4] + px;
  }
  clear() {
    for (let i = 0; i < this.table.data.length; i++) {
      if (this.table.data[i] !== NO_PAGE) { this.free.push(this.table.data[i]); this.table.set(i, NO_PAGE); }
    }
    this.layerPages = [0, 0];
    for (let i = 0; i < 2 * this.cellCount; i++) this.cells.set(i, 0);
  }
  // Applies an UPDATE message; returns the number of pages written and the bytes uploaded.
  apply(buf) {
    const dv = new DataView(buf);
    const flags = dv.getUint8(1);
    const nCells = dv.getUint32(20, true), nPages = dv.getUint32(24, true), nDropped = dv.getUint32(28, true);
    if (flags & 1) this.clear();
    let at = UPDATE_HEADER;
    for (let i = 0; i < nCells; i++, at += 8) {
      const cell = dv.getUint32(at, true), layer = dv.getUint8(at + 4), lod = dv.getUint8(at + 5);
      if (cell < this.cellCount && layer < 2) this.cells.set(layer * this.cellCount + cell, lod);
    }
    for (let i = 0; i < nPages; i++) {
      const layer = dv.getUint8(at), lod = dv.getUint8(at + 1);
      const px = dv.getUint32(at + 4, true), py = dv.getUint32(at + 8, true);
      at += 12;
      const texels = new Float32Array(buf, at, PAGE_FLOATS);
      at += PAGE_FLOATS * 4;
      if (layer > 1 || lod >= this.scene.lods) continue;
      const e = this.entry(layer, lod, px, py);
      let slot = this.table.data[e];
      if (slot === NO_PAGE) {
        if (this.free.length === 0) this.grow(this.capacityRows * 2);
        slot = this.free.pop();
        this.table.set(e, slot);
        this.layerPages[layer]++;
      }
      const column = slot % POOL_COLUMNS, poolRow = Math.floor(slot / POOL_COLUMNS);
      const sx = column * PAGE_SIDE, sy = poolRow * PAGE_SIDE;
      // Into the mirror; the texture gets the touched rows' spans below.
      for (let row = 0; row < PAGE_SIDE; row++) {
        this.poolData.set(texels.subarray(row * PAGE_SIDE * 4, (row + 1) * PAGE_SIDE * 4),
          ((sy + row) * POOL_COLUMNS * PAGE_SIDE + sx) * 4);
      }
      if (!this.dirty.has(poolRow)) this.dirty.set(poolRow, new Set());
      this.dirty.get(poolRow).add(column);
    }
    for (let i = 0; i < nDropped; i++, at += 12) {
      const layer = dv.getUint8(at), lod = dv.getUint8(at + 1);
      const px = dv.getUint32(at + 4, true), py = dv.getUint32(at + 8, true);
      if (layer > 1 || lod >= this.scene.lods) continue;
      const e = this.entry(layer, lod, px, py);
      if (this.table.data[e] !== NO_PAGE) {
        this.free.push(this.table.data[e]);
        this.table.set(e, NO_PAGE);
        this.layerPages[layer]--;
      }
    }
    const bytes = this.uploadDirty();
    this.table.upload();
    this.cells.upload();
    return { pages: nPages, bytes };
  }
  dispose() {
    this.gl.deleteTexture(this.pool);
    this.table.dispose();
    this.cells.dispose();
  }
}
