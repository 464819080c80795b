// The page's socket, in a dedicated worker (docs/SERVE.md). The page's main thread can be
// held for a whole frame by a synchronous GL call (the emulated headset asks the GL for its
// clear values at each frame's start, which waits for the GPU to finish the last frame),
// and Chromium reads a large socket message in chunks, each a task of the thread that owns
// the socket: on the main thread an update of ~200 KB took several frames to arrive. Here
// each message is read whole, off the main thread, numbered, and handed to the page:
// - through a ring in shared memory when the page gave one (a cross-origin isolated page):
//   the page reads it whenever it runs, a frame's start included, without waiting for a
//   task of its own;
// - as a posted message otherwise, and for what does not fit the ring's free space.
// The page applies them in their numbers' order.
let ws = null;
let ring = null;
let index = 0;

onmessage = (ev) => {
  const m = ev.data;
  if (m && m.connect) {
    if (m.ring) ring = { bytes: new Uint8Array(m.ring.data), state: new Int32Array(m.ring.state), write: 0 };
    return connect(m.connect);
  }
  if (ws && ws.readyState === 1) ws.send(m);
};

// Ring layout: state[0] = bytes in use (Atomics), entries of u32 index, u32 length, the
// message, padded to 4 bytes; an entry may wrap around the end.
function put(i, data) {
  const n = data.byteLength, need = 8 + ((n + 3) & ~3), cap = ring.bytes.length;
  if (cap - Atomics.load(ring.state, 0) < need) return false;
  const head = new Uint8Array(8);
  new DataView(head.buffer).setUint32(0, i, true);
  new DataView(head.buffer).setUint32(4, n, true);
  const copy = (src) => {
    const first = Math.min(src.length, cap - ring.write);
    ring.bytes.set(src.subarray(0, first), ring.write);
    ring.bytes.set(src.subarray(first), 0);
    ring.write = (ring.write + src.length) % cap;
  };
  copy(head);
  copy(new Uint8Array(data));
  ring.write = (ring.write + (need - 8 - n)) % cap;
  Atomics.add(ring.state, 0, need);
  return true;
}

function connect(url) {
  ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => postMessage({ open: true });
  ws.onclose = () => postMessage({ closed: true });
  ws.onmessage = (ev) => {
    // When it arrived (ms, the page's clock: both share the time origin's scale).
    const i = index++, at = performance.timeOrigin + performance.now();
    if (typeof ev.data !== "string" && ring && put(i, ev.data)) postMessage({ ring: i, at });
    else if (typeof ev.data === "string") postMessage({ index: i, text: ev.data, at });
    else postMessage({ index: i, binary: ev.data, at }, [ev.data]);
  };
}
