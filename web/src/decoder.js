// The workers index.html started while the page loaded, taken once.
function earlyWorkers() {
  const workers = window.__raillomerWorkers ?? [];
  delete window.__raillomerWorkers;
  return workers;
}

// A pool of tile workers: load(url) resolves with the tile's decoded points.
export class DecoderPool {
  constructor(size = 2) {
    this.workers = [];
    this.jobs = new Map();
    this.next = 0;
    this.seq = 0;
    const early = earlyWorkers();
    for (let i = 0; i < size; i++) {
      const worker =
        early[i] ?? new Worker(new URL('./decoder.worker.js', import.meta.url), { type: 'module' });
      worker.onmessage = (event) => this.done(event.data);
      worker.onerror = (event) => this.failAll(`the decoder failed: ${event.message}`);
      this.workers.push(worker);
    }
  }

  /** Fetches and decodes a tile in a worker; `signal` aborts it (an AbortError). */
  load(url, signal) {
    const id = ++this.seq;
    const worker = this.workers[this.next++ % this.workers.length];
    return new Promise((resolve, reject) => {
      this.jobs.set(id, { resolve, reject });
      worker.postMessage({ id, url });
      signal?.addEventListener('abort', () => worker.postMessage({ cancel: id }), { once: true });
    });
  }

  done(message) {
    const job = this.jobs.get(message.id);
    if (!job) return;
    this.jobs.delete(message.id);
    if (message.aborted) job.reject(new DOMException('the tile left the view', 'AbortError'));
    else if (message.error) job.reject(new Error(message.error));
    else job.resolve(message);
  }

  failAll(error) {
    for (const job of this.jobs.values()) job.reject(new Error(error));
    this.jobs.clear();
  }
}
