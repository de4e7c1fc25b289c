// Loads and decodes tiles (Draco point clouds) off the main thread with Google's draco3d
// decoder: {id, url} is fetched (revalidated by its ETag) and answered with {id, positions
// (Float32Array, offsets from the tile origin), intensities (Uint8Array), points} or {id, error};
// {cancel: id} aborts a fetch still on its way. The main thread, busy compiling shaders or
// drawing in software, holds up neither.
import DracoDecoderModule from 'draco3d/draco_decoder_nodejs.js';
import wasmUrl from 'draco3d/draco_decoder.wasm?url';
import { errorOf } from './api.js';

const ready = fetch(wasmUrl)
  .then((res) => {
    if (!res.ok) throw new Error(`the Draco decoder (${wasmUrl}) did not load: ${res.status}`);
    return res.arrayBuffer();
  })
  .then((wasmBinary) => DracoDecoderModule({ wasmBinary }));

function decode(draco, bytes) {
  const buffer = new draco.DecoderBuffer();
  const decoder = new draco.Decoder();
  const cloud = new draco.PointCloud();
  try {
    buffer.Init(bytes, bytes.length);
    const status = decoder.DecodeBufferToPointCloud(buffer, cloud);
    if (!status.ok()) throw new Error(`not a Draco point cloud: ${status.error_msg()}`);
    const n = cloud.num_points();
    const position = decoder.GetAttribute(
      cloud,
      decoder.GetAttributeId(cloud, draco.POSITION),
    );
    const positions = new Float32Array(n * 3);
    const ptr = draco._malloc(n * 3 * 4);
    decoder.GetAttributeDataArrayForAllPoints(cloud, position, draco.DT_FLOAT32, n * 12, ptr);
    positions.set(new Float32Array(draco.HEAPF32.buffer, ptr, n * 3));
    draco._free(ptr);
    const intensities = new Uint8Array(n);
    const genericId = decoder.GetAttributeId(cloud, draco.GENERIC);
    if (genericId >= 0) {
      const generic = decoder.GetAttribute(cloud, genericId);
      const p = draco._malloc(n);
      decoder.GetAttributeDataArrayForAllPoints(cloud, generic, draco.DT_UINT8, n, p);
      intensities.set(new Uint8Array(draco.HEAPU8.buffer, p, n));
      draco._free(p);
    }
    return { positions, intensities, points: n };
  } finally {
    draco.destroy(cloud);
    draco.destroy(decoder);
    draco.destroy(buffer);
  }
}

const inFlight = new Map(); // id -> AbortController

async function load(id, url) {
  const controller = new AbortController();
  inFlight.set(id, controller);
  try {
    const res = await fetch(url, { cache: 'no-cache', signal: controller.signal });
    if (!res.ok) throw await errorOf(res);
    const bytes = new Int8Array(await res.arrayBuffer());
    const draco = await ready;
    const out = decode(draco, bytes);
    self.postMessage({ id, ...out }, [out.positions.buffer, out.intensities.buffer]);
  } catch (e) {
    if (e.name === 'AbortError') self.postMessage({ id, aborted: true });
    else self.postMessage({ id, error: String(e.message || e) });
  } finally {
    inFlight.delete(id);
  }
}

self.onmessage = (event) => {
  const { id, url, cancel } = event.data;
  if (cancel !== undefined) inFlight.get(cancel)?.abort();
  else load(id, url);
};
