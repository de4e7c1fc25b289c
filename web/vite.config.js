import { defineConfig } from 'vite';

// index.html starts the tile workers before the viewer's code runs; the built page learns the
// worker's hashed file name here (without a build, as under `vite dev`, the viewer starts them).
const workerUrlInHtml = {
  name: 'raillomer-worker-url',
  transformIndexHtml: {
    order: 'post',
    handler(html, ctx) {
      const worker = Object.keys(ctx.bundle ?? {}).find((f) => /decoder\.worker-[\w-]+\.js$/.test(f));
      return html.replace('__RAILLOMER_WORKER_URL__', worker ? `/${worker}` : '');
    },
  },
};

// The stylesheet goes inline (and is not emitted as a file of its own): a linked one holds back
// index.html's early scripts (the WebGL context is made at the view's laid-out size) until it
// has arrived.
const inlineStylesheet = {
  name: 'raillomer-inline-css',
  transformIndexHtml: {
    order: 'post',
    handler(html, ctx) {
      return html.replace(/<link rel="stylesheet"[^>]*href="\/([^"]+\.css)"[^>]*>/g, (tag, file) => {
        const css = ctx.bundle?.[file];
        if (!css) return tag;
        delete ctx.bundle[file];
        return `<style>\n${String(css.source).trim()}\n</style>`;
      });
    },
  },
};

// The built viewer (dist/) is what raillomer-server serves at /: hashed files under /assets/,
// the Draco decoder's wasm among them; nothing is fetched from elsewhere.
export default defineConfig({
  base: '/',
  plugins: [workerUrlInHtml, inlineStylesheet],
  resolve: {
    alias: {
      fs: new URL('./src/node-stub.js', import.meta.url).pathname,
      path: new URL('./src/node-stub.js', import.meta.url).pathname,
    },
  },
  build: {
    outDir: 'dist',
    emptyOutDir: true,
    target: 'es2022',
    chunkSizeWarningLimit: 1200,
  },
  worker: { format: 'es' },
});
