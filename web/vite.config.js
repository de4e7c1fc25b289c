import { defineConfig } from 'vite';

// The built viewer (dist/) is what raillomer-server serves at /: hashed files under /assets/,
// the Draco decoder's wasm among them; nothing is fetched from elsewhere.
export default defineConfig({
  base: '/',
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
