// Builds the dashboard into app/static/ (committed): `npm ci && npm run build` in frontend/.
import { build } from "esbuild";
import { copyFile, mkdir } from "node:fs/promises";

const out = new URL("../app/static/", import.meta.url).pathname;
await mkdir(out, { recursive: true });
await build({
  entryPoints: { app: "src/main.js" },
  bundle: true,
  minify: true,
  format: "esm",
  target: "es2020",
  outdir: out,
  legalComments: "eof",
  logLevel: "info",
});
await copyFile("index.html", `${out}index.html`);
