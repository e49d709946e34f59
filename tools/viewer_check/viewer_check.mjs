// Viewer check: opens rig MCAP logs with a Foxglove layout in an already built Lichtblick web app, in
// headless Chromium, and reports what a user would see: every entry of the Problems tab, and for each
// panel of the layout whether it shows data, waits for a message, stays empty or shows an error (plus
// the Plot legend's error icons). Screenshots go to --out.
//
// Per log, two passes in fresh browser profiles: (1) the layout as given, the log played through to
// its end at 5x: screenshots, panel states, Problems; (2) the same layout with every Plot series in a
// saturated probe colour, the log sought to its end: each series' pixels counted by hue.
//
// It builds nothing: --app must be a Lichtblick web build directory (index.html + bundles). The app and
// the logs are served by a small HTTP server on 127.0.0.1 with Range support; the layout replaces the
// LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER of the served index.html, in memory (the app directory is
// never written). Chromium is kept on 127.0.0.1 (host resolver rules, a dead proxy, no background
// networking) and runs with a throw-away profile.
//
// Usage: node viewer_check.mjs --app DIR --log FILE.mcap [--log FILE2.mcap ...] --layout LAYOUT.json
//                              --out DIR [--chromium PATH] [--timeout SECONDS]
// Exit status: 0 every log opened with no Problems entries, no legend error icons and data in every
// panel; 1 otherwise; 2 bad arguments.

import { createReadStream } from "node:fs";
import { access, constants, mkdir, mkdtemp, open, readFile, rm, stat, writeFile } from "node:fs/promises";
import http from "node:http";
import os from "node:os";
import path from "node:path";
import { parseArgs } from "node:util";

import puppeteer from "puppeteer-core";

const PLACEHOLDER = "/*LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER*/";
const LOG_ROUTE = "/__viewer_check__/";
const MCAP_MAGIC = Buffer.from([0x89, 0x4d, 0x43, 0x41, 0x50, 0x30, 0x0d, 0x0a]);
const PLAYBACK_SPEED_LABEL = "5×"; // the fastest of the app's playback speeds (1.10.x)
const VIEWPORT = { width: 1600, height: 1000 };
const MISMATCH_TEXT = "Mismatch in the number of elements in x-axis and y-axis messages";
// A series counts as drawn when at least this many pixels of its colour show in the plot area
// (a dot of about 4 px diameter); a 1 px point or an empty series stays below it.
const MIN_SERIES_PIXELS = 12;
// Probe colours for Plot series (pass 2): fully saturated, 30 degrees of hue or more apart, so that
// neither the greys of axes, grid and text nor another series match. The app draws a series' points
// in a darker shade of its colour (same hue), so a pixel counts for a probe colour by hue: within
// PROBE_HUE_TOLERANCE_DEG of it, with saturation of at least 0.5 and not near black.
const PROBE_COLOURS = ["#ff0000", "#00ff00", "#0000ff", "#ff00ff", "#00ffff", "#ff8000", "#8000ff", "#ffff00"];
const PROBE_HUE_TOLERANCE_DEG = 12;
// A State Transitions row counts as drawn when coloured bars cover at least this many pixel columns
// (the grey playback cursor and axes are not coloured).
const MIN_STATE_COLUMNS = 4;
// 3D panel: the hue of the rig scene's line arrow (RGB 0.98, 0.60, 0.10: 36°) and how many pixels of it
// count as the scene drawn (the arrow is at least 3 cm long, tens of pixels at the layout's zoom).
const SCENE_ARROW_HUE_DEG = 36;
const SCENE_HUE_TOLERANCE_DEG = 8;
const MIN_SCENE_PIXELS = 12;
const STATE_ROW_HEIGHT = 64; // the State Transitions panel's height per path, from the chart's top (1.10.x)
const EXPECTS_APP =
  "expected a Lichtblick web build directory (the web/.webpack output of a Lichtblick 1.10.x web build " +
  "made from its source: index.html carrying the LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER marker, " +
  "beside the JavaScript bundles)";

class UsageError extends Error {}

const CONTENT_TYPES = {
  ".html": "text/html; charset=utf-8",
  ".js": "text/javascript; charset=utf-8",
  ".mjs": "text/javascript; charset=utf-8",
  ".css": "text/css; charset=utf-8",
  ".json": "application/json",
  ".map": "application/json",
  ".wasm": "application/wasm",
  ".woff2": "font/woff2",
  ".woff": "font/woff",
  ".ttf": "font/ttf",
  ".png": "image/png",
  ".svg": "image/svg+xml",
  ".ico": "image/x-icon",
  ".webmanifest": "application/manifest+json",
  ".txt": "text/plain; charset=utf-8",
  ".mcap": "application/octet-stream",
};

// ---------------------------------------------------------------------------------------------- arguments

function parseArguments(argv) {
  let parsed;
  try {
    parsed = parseArgs({
      args: argv,
      options: {
        app: { type: "string" },
        log: { type: "string", multiple: true },
        layout: { type: "string" },
        out: { type: "string" },
        chromium: { type: "string", default: "/usr/bin/chromium" },
        timeout: { type: "string", default: "600" },
        help: { type: "boolean", short: "h" },
      },
      strict: true,
      allowPositionals: false,
    });
  } catch (error) {
    throw new UsageError(error.message);
  }
  const { values } = parsed;
  if (values.help) {
    process.stdout.write(
      "usage: node viewer_check.mjs --app DIR --log FILE.mcap [--log ...] --layout LAYOUT.json --out DIR\n" +
        "                             [--chromium PATH] [--timeout SECONDS]\n",
    );
    process.exit(0);
  }
  for (const name of ["app", "log", "layout", "out"]) {
    if (values[name] == undefined) {
      throw new UsageError(`--${name} is required${name === "app" ? `: ${EXPECTS_APP}` : ""}`);
    }
  }
  const timeoutS = Number(values.timeout);
  if (!Number.isFinite(timeoutS) || timeoutS < 10 || timeoutS > 7200) {
    throw new UsageError(`--timeout ${values.timeout}: expected seconds per log, 10 to 7200`);
  }
  return {
    appDir: path.resolve(values.app),
    logFiles: values.log.map((file) => path.resolve(file)),
    layoutFile: path.resolve(values.layout),
    outDir: path.resolve(values.out),
    chromium: values.chromium,
    timeoutMs: timeoutS * 1000,
  };
}

async function loadAppIndex(appDir) {
  const info = await stat(appDir).catch(() => undefined);
  if (!info?.isDirectory()) {
    throw new UsageError(`--app ${appDir}: not a directory; ${EXPECTS_APP}`);
  }
  const indexHtml = await readFile(path.join(appDir, "index.html"), "utf8").catch(() => undefined);
  if (indexHtml == undefined) {
    throw new UsageError(`--app ${appDir}: no index.html; ${EXPECTS_APP}`);
  }
  if (!indexHtml.includes(PLACEHOLDER)) {
    throw new UsageError(
      `--app ${appDir}/index.html: no ${PLACEHOLDER} marker (not a Lichtblick web build, or one whose ` +
        `index.html was already edited); ${EXPECTS_APP}`,
    );
  }
  return indexHtml;
}

function layoutLeaves(node, where) {
  if (typeof node === "string") {
    return [node];
  }
  if (node && typeof node === "object" && "first" in node && "second" in node) {
    return [...layoutLeaves(node.first, where), ...layoutLeaves(node.second, where)];
  }
  throw new UsageError(`${where}: field layout: expected a panel id or {first, second, direction} node`);
}

async function loadLayout(layoutFile) {
  const text = await readFile(layoutFile, "utf8").catch(() => undefined);
  if (text == undefined) {
    throw new UsageError(`--layout ${layoutFile}: cannot read the file`);
  }
  let layout;
  try {
    layout = JSON.parse(text);
  } catch (error) {
    throw new UsageError(`--layout ${layoutFile}: not JSON (${error.message})`);
  }
  if (!layout || typeof layout !== "object" || typeof layout.configById !== "object" || !layout.layout) {
    throw new UsageError(`--layout ${layoutFile}: expected a Foxglove layout object with configById and layout`);
  }
  const panels = layoutLeaves(layout.layout, `--layout ${layoutFile}`).map((id) => {
    const config = layout.configById[id];
    if (!config) {
      throw new UsageError(`--layout ${layoutFile}: field configById: no entry for panel ${id}`);
    }
    return { id, type: id.split("!")[0], title: config.foxglovePanelTitle ?? id, config };
  });
  return { layout, panels };
}

async function checkLog(file) {
  const handle = await open(file, "r").catch(() => undefined);
  if (!handle) {
    throw new UsageError(`--log ${file}: cannot read the file`);
  }
  try {
    const head = Buffer.alloc(MCAP_MAGIC.length);
    await handle.read(head, 0, head.length, 0);
    if (!head.equals(MCAP_MAGIC)) {
      throw new UsageError(`--log ${file}: not an MCAP file (no MCAP magic at its start)`);
    }
  } finally {
    await handle.close();
  }
  if (path.extname(file) !== ".mcap") {
    throw new UsageError(`--log ${file}: the name must end in .mcap (the app picks its reader by extension)`);
  }
}

async function checkChromium(file) {
  try {
    await access(file, constants.X_OK);
  } catch {
    throw new UsageError(`--chromium ${file}: not an executable (install Debian's chromium: apt-get install chromium)`);
  }
}

// ------------------------------------------------------------------------------------------------- server

function parseRange(header, size) {
  // One "bytes=START-END", "bytes=START-" or "bytes=-SUFFIX" range; anything else is served whole.
  const match = /^bytes=(\d*)-(\d*)$/.exec(header ?? "");
  if (!match || (match[1] === "" && match[2] === "")) {
    return undefined;
  }
  let start;
  let end;
  if (match[1] === "") {
    start = Math.max(0, size - Number(match[2]));
    end = size - 1;
  } else {
    start = Number(match[1]);
    end = match[2] === "" ? size - 1 : Math.min(Number(match[2]), size - 1);
  }
  return start > end || start >= size ? "unsatisfiable" : { start, end };
}

async function sendFile(req, res, file) {
  const info = await stat(file).catch(() => undefined);
  if (!info?.isFile()) {
    res.writeHead(404, { "Content-Type": "text/plain" }).end("not found\n");
    return;
  }
  const headers = {
    "Content-Type": CONTENT_TYPES[path.extname(file)] ?? "application/octet-stream",
    "Accept-Ranges": "bytes",
    "Cache-Control": "no-store",
  };
  const range = parseRange(req.headers.range, info.size);
  if (range === "unsatisfiable") {
    res.writeHead(416, { ...headers, "Content-Range": `bytes */${info.size}` }).end();
    return;
  }
  const { start, end } = range ?? { start: 0, end: info.size - 1 };
  res.writeHead(range ? 206 : 200, {
    ...headers,
    "Content-Length": String(end - start + 1),
    ...(range ? { "Content-Range": `bytes ${start}-${end}/${info.size}` } : {}),
  });
  if (req.method === "HEAD" || info.size === 0) {
    res.end();
    return;
  }
  createReadStream(file, { start, end }).pipe(res);
}

function startServer({ appDir, indexHtml, logFiles }) {
  const logsByName = new Map(logFiles.map((file, index) => [`${index}-${path.basename(file)}`, file]));
  const server = http.createServer((req, res) => {
    if (req.method !== "GET" && req.method !== "HEAD") {
      res.writeHead(405).end();
      return;
    }
    const { pathname } = new URL(req.url, "http://127.0.0.1");
    const decoded = decodeURIComponent(pathname);
    if (decoded === "/" || decoded === "/index.html") {
      const body = Buffer.from(indexHtml, "utf8");
      res.writeHead(200, {
        "Content-Type": CONTENT_TYPES[".html"],
        "Content-Length": String(body.length),
        "Cache-Control": "no-store",
      });
      res.end(req.method === "HEAD" ? undefined : body);
      return;
    }
    if (decoded.startsWith(LOG_ROUTE)) {
      const file = logsByName.get(decoded.slice(LOG_ROUTE.length));
      if (!file) {
        res.writeHead(404).end();
        return;
      }
      sendFile(req, res, file).catch(() => res.destroy());
      return;
    }
    const file = path.join(appDir, path.normalize(decoded));
    if (!file.startsWith(appDir + path.sep)) {
      res.writeHead(403).end();
      return;
    }
    sendFile(req, res, file).catch(() => res.destroy());
  });
  return new Promise((resolve, reject) => {
    server.once("error", reject);
    server.listen(0, "127.0.0.1", () => {
      const { port } = server.address();
      const logUrls = new Map([...logsByName].map(([name, file]) => [file, `http://127.0.0.1:${port}${LOG_ROUTE}${name}`]));
      resolve({ server, port, logUrls });
    });
  });
}

function injectLayout(indexHtml, layout) {
  // The placeholder sits inside a <script>; "<" is escaped so no string in the layout can end the script.
  const literal = JSON.stringify(layout).replace(/</g, "\\u003c");
  return indexHtml.replace(PLACEHOLDER, () => literal);
}

// ------------------------------------------------------------------------------------------------ browser

function chromiumArgs(userDataDir) {
  return [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    `--user-data-dir=${userDataDir}`,
    // Only 127.0.0.1 resolves; any other host fails, and anything that still tries to leave goes to a
    // proxy on the discard port, which answers nothing.
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
    "--proxy-server=http://127.0.0.1:9",
    "--proxy-bypass-list=127.0.0.1",
    `--window-size=${VIEWPORT.width},${VIEWPORT.height}`,
  ];
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

async function waitFor(page, fn, arg, timeoutMs, what) {
  try {
    await page.waitForFunction(fn, { timeout: timeoutMs, polling: 250 }, arg);
  } catch (error) {
    throw new Error(`timed out after ${Math.round(timeoutMs / 1000)} s waiting for ${what}`);
  }
}

async function clickMenuItem(page, label) {
  const clicked = await page.evaluate((text) => {
    const item = [...document.querySelectorAll('[role="menuitem"]')].find((el) => el.textContent.trim() === text);
    item?.click();
    return item != undefined;
  }, label);
  if (!clicked) {
    throw new Error(`no "${label}" entry in the playback speed menu`);
  }
}

// Where the scrubber's marker stands, as a fraction of the log (undefined before the log is open).
function playbackFraction(page) {
  return page.evaluate(() => {
    const marker = document.querySelector('[class*="Slider-root"] > [class*="-marker"]');
    const left = marker ? /left:\s*([\d.]+)%/.exec(marker.getAttribute("style") ?? "") : undefined;
    return left ? Number(left[1]) / 100 : undefined;
  });
}

async function waitForOpenLog(page, deadline) {
  await waitFor(
    page,
    () => {
      const button = document.querySelector('button[title="Play"]');
      return button != undefined && !button.disabled;
    },
    undefined,
    Math.max(1000, deadline - Date.now()),
    "the log to open (an enabled Play button)",
  );
}

// Plays the log from its start to its end at the fastest speed, so that every panel that accumulates
// messages (the log panel) has seen all of them, and the panels that draw the whole log from the
// preloaded blocks have them. Playback can pause on its own (buffering), so Play is pressed again
// whenever it shows while the scrubber is short of the end.
async function playThrough(page, deadline) {
  const remaining = () => Math.max(1000, deadline - Date.now());
  await waitForOpenLog(page, deadline);
  await page.click('[data-testid="PlaybackSpeedControls-Dropdown"]');
  await page.waitForSelector('[role="menuitem"]', { timeout: remaining() });
  await clickMenuItem(page, PLAYBACK_SPEED_LABEL);
  await waitFor(page, () => document.querySelector('[role="menuitem"]') == undefined, undefined, remaining(), "the speed menu to close");
  for (;;) {
    const reached = await playbackFraction(page);
    if (reached != undefined && reached >= 0.999) {
      break;
    }
    if (Date.now() > deadline) {
      throw new Error(`timed out with playback at ${reached == undefined ? "?" : (reached * 100).toFixed(1)} % of the log`);
    }
    const play = await page.$('button[title="Play"]:not([disabled])');
    if (play) {
      await play.click();
    }
    await sleep(500);
  }
  await waitFor(page, () => document.querySelector('button[title="Play"]') != undefined, undefined, remaining(), "playback to stop at the end of the log");
}

// Seeks straight to the end of the log (a click at the right end of the scrubber). Enough for the
// panels that draw the whole log from the preloaded blocks (Plot, State Transitions), not for the log
// panel, which only shows what playback delivered.
async function seekToEnd(page, deadline) {
  await waitForOpenLog(page, deadline);
  for (;;) {
    const reached = await playbackFraction(page);
    if (reached != undefined && reached >= 0.999) {
      return;
    }
    if (Date.now() > deadline) {
      throw new Error(`timed out seeking to the end, at ${reached == undefined ? "?" : (reached * 100).toFixed(1)} % of the log`);
    }
    const slider = await page.$('[class*="Slider-root"]');
    const box = await slider?.boundingBox();
    if (box) {
      await page.mouse.click(box.x + box.width - 1, box.y + box.height / 2);
    }
    await sleep(500);
  }
}

// ------------------------------------------------------------------------------------------ measurements

// Runs in the page: the DOM side of every panel (title, error, empty-state text, table rows, log rows,
// legend rows with their colours and error icons) and the screen rectangles the pixel counts need.
function readPanelsInPage({ panelIds, mismatchText }) {
  const rectOf = (el) => {
    const r = el.getBoundingClientRect();
    return { x: r.left, y: r.top, width: r.width, height: r.height };
  };
  const visibleText = (el) => (el.innerText ?? "").replace(/\s+/g, " ").trim();
  return panelIds.map((id) => {
    const root = document.querySelector(`[data-testid~="panel-mouseenter-container"][data-testid~=${JSON.stringify(id)}]`);
    if (!root) {
      return { id, present: false };
    }
    const header = root.querySelector('[data-testid="mosaic-drag-handle"]');
    const text = visibleText(root);
    const headerText = header ? visibleText(header) : "";
    const body = text.startsWith(headerText) ? text.slice(headerText.length).trim() : text;
    const errorBoundary = text.includes("Dismiss this error");
    const emptyTexts = [...root.querySelectorAll(".MuiTypography-root")]
      .map((el) => visibleText(el))
      .filter(
        (t) =>
          ["Waiting for next message…", "No topic selected"].includes(t) || t.startsWith("Cannot render primitive values"),
      );
    const canvas = root.querySelector("canvas");
    const tableRows = [...root.querySelectorAll("table tbody tr")].map((tr) => visibleText(tr));
    const logRows = [...root.querySelectorAll("div > span:first-child")]
      .filter((span) => /^\[\s*(DEBUG|INFO|WARN|ERROR|FATAL)\]$/.test(span.textContent.trim()))
      .map((span) => visibleText(span.parentElement.parentElement));
    const legendRows = [...root.querySelectorAll('[title="Toggle visibility"]')].map((checkbox) => {
      const nameCell = checkbox.parentElement.nextElementSibling;
      const valueCell = nameCell?.nextElementSibling;
      const hasValue = valueCell != undefined && valueCell.querySelector("button") == undefined;
      // The only icon a legend name cell carries is the error icon (its tooltip is the mismatch text).
      const errorIcon =
        nameCell != undefined &&
        ([...nameCell.querySelectorAll("[aria-label]")].some((el) => el.getAttribute("aria-label") === mismatchText) ||
          nameCell.querySelector("svg") != undefined);
      return {
        label: nameCell ? visibleText(nameCell) : "",
        color: getComputedStyle(checkbox).color,
        enabled: checkbox.querySelector("input")?.checked ?? true,
        value: hasValue ? visibleText(valueCell) : undefined,
        mismatch: errorIcon,
      };
    });
    // Overlays drawn on top of a chart, left out of the pixel counts: the Plot legend and its
    // "Reset view" button, the State Transitions path labels.
    const firstCheckbox = root.querySelector('[title="Toggle visibility"]');
    const legendRoot = firstCheckbox?.parentElement?.parentElement?.parentElement ?? undefined;
    const overlays = [
      legendRoot,
      root.querySelector('[data-testid="plot-reset-view-button"] button'),
      ...root.querySelectorAll('[class*="chartOverlay"] .MuiButtonGroup-root'),
    ].filter((el) => el != undefined);
    return {
      id,
      present: true,
      title: headerText,
      bodyText: body.slice(0, 400),
      errorBoundary,
      errorText: errorBoundary ? body.slice(0, 400) : undefined,
      emptyTexts,
      canvasRect: canvas ? rectOf(canvas) : undefined,
      overlayRects: overlays.map(rectOf),
      tableRows,
      logRows,
      legendRows,
    };
  });
}

// Runs in the page: decodes a PNG screenshot (base64) and counts, inside `rect` and outside the masked
// rectangles, the pixels near each of `colors`, and per horizontal band of `bands` the pixel columns
// holding saturated (coloured, not grey) pixels. All coordinates are window pixels.
async function countPixelsInPage({ png, rect, masks, hues, hueTolerance, bands }) {
  const image = new Image();
  image.src = `data:image/png;base64,${png}`;
  await image.decode();
  const canvas = document.createElement("canvas");
  canvas.width = image.naturalWidth;
  canvas.height = image.naturalHeight;
  const ctx = canvas.getContext("2d", { willReadFrequently: true });
  ctx.drawImage(image, 0, 0);
  const x0 = Math.max(0, Math.floor(rect.x));
  const y0 = Math.max(0, Math.floor(rect.y));
  const x1 = Math.min(canvas.width, Math.ceil(rect.x + rect.width));
  const y1 = Math.min(canvas.height, Math.ceil(rect.y + rect.height));
  const huePixels = hues.map(() => 0);
  const bandColumnSets = bands.map(() => new Set());
  if (x1 <= x0 || y1 <= y0) {
    return { huePixels, bandColumns: bands.map(() => 0) };
  }
  const { data } = ctx.getImageData(x0, y0, x1 - x0, y1 - y0);
  const masked = (x, y) => masks.some((m) => x >= m.x && x < m.x + m.width && y >= m.y && y < m.y + m.height);
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      if (masked(x, y)) {
        continue;
      }
      const i = ((y - y0) * (x1 - x0) + (x - x0)) * 4;
      const r = data[i];
      const g = data[i + 1];
      const b = data[i + 2];
      const max = Math.max(r, g, b);
      const min = Math.min(r, g, b);
      if (hues.length > 0 && max >= 60 && (max - min) / max >= 0.5) {
        const delta = max - min;
        const sector = max === r ? ((g - b) / delta + 6) % 6 : max === g ? (b - r) / delta + 2 : (r - g) / delta + 4;
        const hue = sector * 60;
        hues.forEach((h, k) => {
          const apart = Math.abs(hue - h);
          if (Math.min(apart, 360 - apart) <= hueTolerance) {
            huePixels[k] += 1;
          }
        });
      }
      if (max > 60 && (max - min) / max > 0.35) {
        bands.forEach((band, k) => {
          if (y >= band.y && y < band.y + band.height) {
            bandColumnSets[k].add(x);
          }
        });
      }
    }
  }
  return { huePixels, bandColumns: bandColumnSets.map((s) => s.size) };
}

// Waits until the whole window has stopped changing (two equal screenshots 1 s apart), at most limitMs.
// Returns the last screenshot (PNG) and whether it settled.
async function settleWindow(page, limitMs) {
  const until = Date.now() + limitMs;
  await page.mouse.move(1, 1);
  let last = Buffer.from(await page.screenshot({ type: "png" }));
  while (Date.now() < until) {
    await sleep(1000);
    const next = Buffer.from(await page.screenshot({ type: "png" }));
    if (next.equals(last)) {
      return { png: next, settled: true };
    }
    last = next;
  }
  return { png: last, settled: false };
}

// The layout as given, with each Plot series drawn in a probe colour (a saturated colour no other
// series of that panel, no axis and no grid line has), so that its pixels can be told apart. Only
// colours change: sizes, scales and everything else stay as in the layout.
function probeLayout(layout) {
  const copy = structuredClone(layout);
  for (const [id, config] of Object.entries(copy.configById)) {
    if (id.split("!")[0] === "Plot" && Array.isArray(config.paths)) {
      config.paths.forEach((p, k) => {
        p.color = PROBE_COLOURS[k % PROBE_COLOURS.length];
      });
    }
  }
  return copy;
}

function hueOf(hex) {
  const [r, g, b] = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));
  const max = Math.max(r, g, b);
  const delta = max - Math.min(r, g, b);
  const sector = max === r ? ((g - b) / delta + 6) % 6 : max === g ? (b - r) / delta + 2 : (r - g) / delta + 4;
  return sector * 60;
}

// Reads every panel of the page (pass 1, the layout as given): state, legend errors, and the State
// Transitions rows from the screenshot. Plot series pixel counts come from the probe pass.
async function readPanels(page, panels, png) {
  const dom = await page.evaluate(readPanelsInPage, { panelIds: panels.map((p) => p.id), mismatchText: MISMATCH_TEXT });
  const results = [];
  for (const [index, panel] of panels.entries()) {
    const d = dom[index];
    const result = { id: panel.id, type: panel.type, title: panel.title, shownTitle: d.title ?? null };
    results.push(result);
    if (!d.present) {
      Object.assign(result, { state: "missing", detail: "the panel is not on the page" });
      continue;
    }
    if (d.errorBoundary) {
      Object.assign(result, { state: "error", detail: d.errorText });
      continue;
    }
    if (panel.type === "Plot") {
      result.series = d.legendRows.slice(0, (panel.config.paths ?? []).length).map((row) => ({
          label: row.label,
          color: row.color,
          enabled: row.enabled,
          pixels: null,
          visibility: null,
          legendValue: row.value ?? null,
          legendError: row.mismatch ? MISMATCH_TEXT : null,
        }));
      result.legendErrors = result.series.filter((s) => s.legendError).map((s) => `${s.label}: ${s.legendError}`);
      result.state = "unmeasured";
      result.detail = "series not measured";
    } else if (panel.type === "StateTransitions") {
      const paths = panel.config.paths ?? [];
      let bandColumns = paths.map(() => 0);
      if (d.canvasRect) {
        const top = d.canvasRect.y;
        ({ bandColumns } = await page.evaluate(countPixelsInPage, {
          png: png.toString("base64"),
          rect: d.canvasRect,
          masks: d.overlayRects,
          hues: [],
          hueTolerance: 0,
          bands: paths.map((_, k) => ({ y: top + k * STATE_ROW_HEIGHT, height: STATE_ROW_HEIGHT })),
        }));
      }
      result.rows = paths.map((p, k) => ({
        path: p.value,
        label: p.label ?? p.value,
        colouredColumns: bandColumns[k],
        drawn: bandColumns[k] >= MIN_STATE_COLUMNS,
      }));
      const drawn = result.rows.filter((r) => r.drawn).length;
      result.state = paths.length > 0 && drawn === paths.length ? "data" : drawn > 0 ? "partial" : "empty";
      result.detail = `${drawn} of ${paths.length} rows drawn`;
    } else if (panel.type === "Table") {
      if (d.tableRows.length > 0) {
        Object.assign(result, { state: "data", detail: `${d.tableRows.length} rows`, tableRows: d.tableRows });
      } else if (d.emptyTexts.length > 0) {
        Object.assign(result, { state: d.emptyTexts[0].startsWith("Waiting") ? "waiting" : "empty", detail: d.emptyTexts[0] });
      } else {
        Object.assign(result, { state: "empty", detail: d.bodyText || "no table" });
      }
    } else if (panel.type === "RosOut") {
      if (d.logRows.length > 0) {
        Object.assign(result, {
          state: "data",
          detail: `${d.logRows.length} log lines on screen`,
          lastLine: d.logRows[d.logRows.length - 1],
        });
      } else {
        Object.assign(result, { state: "empty", detail: "no log lines" });
      }
    } else if (panel.type === "3D") {
      // The rig's scene draws the line as an orange arrow (rig/log/format/link_scene.py); the viewer's own
      // grid and frame axes are blue, red, green and grey, so orange pixels mean the scene is drawn.
      let orange = 0;
      if (d.canvasRect) {
        ({ huePixels: [orange] } = await page.evaluate(countPixelsInPage, {
          png: png.toString("base64"),
          rect: d.canvasRect,
          masks: [],
          hues: [SCENE_ARROW_HUE_DEG],
          hueTolerance: SCENE_HUE_TOLERANCE_DEG,
          bands: [],
        }));
      }
      Object.assign(result, {
        state: orange >= MIN_SCENE_PIXELS ? "data" : "empty",
        detail: `${orange} px of the scene's orange line arrow`,
        scenePixels: orange,
      });
    } else {
      Object.assign(result, {
        state: "unchecked",
        detail: `this check does not know how to read a ${panel.type} panel (see tools/viewer_check/README.md)`,
      });
    }
  }
  return { results, dom };
}

// Pass 2: in the probe layout, counts each Plot series' pixels by its probe colour and fills in the
// Plot results of pass 1.
async function countSeriesPixels(page, png, d, hues) {
  const { huePixels } = await page.evaluate(countPixelsInPage, {
    png: png.toString("base64"),
    rect: d.canvasRect,
    masks: d.overlayRects,
    hues,
    hueTolerance: PROBE_HUE_TOLERANCE_DEG,
    bands: [],
  });
  return huePixels;
}

async function setSeriesShown(page, panelId, index, shown) {
  const selector = `[data-testid~="panel-mouseenter-container"][data-testid~=${JSON.stringify(panelId)}] [title="Toggle visibility"]`;
  const boxes = await page.$$(selector);
  const checked = await boxes[index].$eval("input", (input) => input.checked);
  if (checked !== shown) {
    await boxes[index].click();
  }
}

// Pass 2: in the probe layout, counts each Plot series' pixels by its probe colour and fills in the
// Plot results of pass 1. A series below the threshold is drawn again alone (the others hidden with
// their legend checkboxes, then shown again): if it shows then, it is "covered" by other series (it
// has data; on this log it lies under them), otherwise it is "absent" (nothing) or "too small" (a few
// pixels, e.g. 1 px points).
async function measurePlots(page, panels, results, png) {
  const dom = await page.evaluate(readPanelsInPage, { panelIds: panels.map((p) => p.id), mismatchText: MISMATCH_TEXT });
  for (const [index, panel] of panels.entries()) {
    const result = results[index];
    const d = dom[index];
    if (panel.type !== "Plot" || result.state !== "unmeasured") {
      continue;
    }
    if (!d.present || !d.canvasRect) {
      Object.assign(result, { state: "empty", detail: "no chart on the page in the probe pass" });
      continue;
    }
    const hues = result.series.map((_, k) => hueOf(PROBE_COLOURS[k % PROBE_COLOURS.length]));
    const huePixels = await countSeriesPixels(page, png, d, hues);
    result.probeChartRect = d.canvasRect;
    result.probeMaskRects = d.overlayRects;
    for (const [k, s] of result.series.entries()) {
      s.pixels = huePixels[k];
      s.visibility = !s.enabled ? "disabled" : s.pixels >= MIN_SERIES_PIXELS ? "drawn" : undefined;
    }
    for (const [k, s] of result.series.entries()) {
      if (s.visibility != undefined) {
        continue;
      }
      const others = result.series.map((o, j) => j).filter((j) => j !== k && result.series[j].enabled);
      for (const j of others) {
        await setSeriesShown(page, panel.id, j, false);
      }
      const { png: alonePng } = await settleWindow(page, 15_000);
      s.pixelsAlone = (await countSeriesPixels(page, alonePng, d, hues))[k];
      for (const j of others) {
        await setSeriesShown(page, panel.id, j, true);
      }
      await settleWindow(page, 15_000);
      s.visibility =
        s.pixelsAlone >= MIN_SERIES_PIXELS ? "covered" : s.pixelsAlone > 0 || s.pixels > 0 ? "too small" : "absent";
    }
    const enabled = result.series.filter((s) => s.enabled);
    const shown = enabled.filter((s) => s.visibility === "drawn" || s.visibility === "covered").length;
    const covered = enabled.filter((s) => s.visibility === "covered").length;
    result.state = enabled.length > 0 && shown === enabled.length ? "data" : shown > 0 ? "partial" : "empty";
    result.detail = `${shown} of ${enabled.length} series drawn${covered > 0 ? ` (${covered} only under other series)` : ""}`;
  }
}

function addEmptyTexts(results, dom) {
  for (const [index, result] of results.entries()) {
    const texts = dom[index].emptyTexts ?? [];
    if (result.state !== "data" && texts.length > 0 && !result.detail.includes(texts[0])) {
      result.detail += `; shows "${texts[0]}"`;
    }
  }
}

// Runs in the page: reads the Problems list (each entry's message and its details).
function readProblemsInPage() {
  const entries = [...document.querySelectorAll(".MuiAccordion-root")];
  return entries.map((entry) => {
    const summary = entry.querySelector(".MuiAccordionSummary-root");
    const details = entry.querySelector(".MuiAccordionDetails-root");
    return {
      message: summary?.getAttribute("title") ?? (summary?.innerText ?? "").trim(),
      details: details ? details.innerText.trim() : "",
    };
  });
}

async function readProblems(page, deadline) {
  const remaining = () => Math.max(1000, deadline - Date.now());
  if (!(await page.$('[data-testid="problems-left"]'))) {
    await page.click('[data-tourid="left-sidebar-button"]');
    await page.waitForSelector('[data-testid="problems-left"]', { timeout: remaining() }).catch(() => undefined);
  }
  const tab = await page.$('[data-testid="problems-left"]');
  if (!tab) {
    throw new Error("no Problems tab in the left sidebar");
  }
  await tab.click();
  await waitFor(
    page,
    () => document.querySelector(".MuiAccordion-root") != undefined || /No problems found/i.test(document.body.innerText),
    undefined,
    remaining(),
    "the Problems tab to show",
  );
  await sleep(500);
  return page.evaluate(readProblemsInPage);
}

// ----------------------------------------------------------------------------------------------- one log

// Opens `url` in a fresh browser, waits for the layout's panels, closes the left sidebar (the panels
// are measured at full width), plays the log through (`play`) or seeks to its end, waits for the
// window to settle and hands the page to `inspect`.
async function withLogAtEnd({ chromium, url, panels, deadline, consoleErrors, timings, play, failShot }, inspect) {
  const started = Date.now();
  const userDataDir = await mkdtemp(path.join(os.tmpdir(), "viewer-check-profile-"));
  const browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true,
    args: chromiumArgs(userDataDir),
    defaultViewport: { ...VIEWPORT, deviceScaleFactor: 1 },
    timeout: 60_000,
  });
  try {
    const page = await browser.newPage();
    page.on("pageerror", (error) => consoleErrors.push(`page error: ${error.message}`));
    page.on("console", (msg) => {
      if (msg.type() === "error") {
        consoleErrors.push(msg.text());
      }
    });
    try {
      await page.goto(url, { waitUntil: "load", timeout: Math.max(1000, deadline - Date.now()) });
      await waitFor(
        page,
        (n) => document.querySelectorAll('[data-testid~="panel-mouseenter-container"]').length >= n,
        panels.length,
        Math.max(1000, deadline - Date.now()),
        `the layout's ${panels.length} panels`,
      );
      const closeLeft = await page.$('[data-testid="sidebar-close-left"]');
      if (closeLeft) {
        await closeLeft.click();
      }
      const opened = Date.now();
      await (play ? playThrough(page, deadline) : seekToEnd(page, deadline));
      const played = Date.now();
      const { png, settled } = await settleWindow(page, Math.min(60_000, Math.max(1000, deadline - Date.now())));
      const value = await inspect(page, png, settled);
      timings.push({
        pass: timings.length + 1,
        open_s: (opened - started) / 1000,
        [play ? "playback_s" : "seek_s"]: (played - opened) / 1000,
        settle_and_read_s: (Date.now() - played) / 1000,
      });
      return value;
    } catch (error) {
      // The page as it was when the check gave up, taken before the browser closes.
      if (await page.screenshot({ path: failShot, type: "png" }).then(() => true, () => false)) {
        error.shot = failShot;
      }
      throw error;
    }
  } finally {
    await browser.close();
    await rm(userDataDir, { recursive: true, force: true });
  }
}

// The browser console's errors, for diagnosis only: each distinct text once with its count, at most 20.
function summariseConsole(lines) {
  const counts = new Map();
  for (const line of lines) {
    counts.set(line, (counts.get(line) ?? 0) + 1);
  }
  return [...counts].slice(0, 20).map(([text, count]) => ({ text: text.slice(0, 500), count }));
}

async function checkOneLog({ chromium, viewUrl, probeUrl, logFile, panels, outDir, timeoutMs }) {
  const stem = path.basename(logFile, ".mcap");
  const deadline = Date.now() + timeoutMs;
  const consoleErrors = [];
  const screenshots = [];
  const timings = [];
  const failShot = path.join(outDir, `${stem}-failed.png`);
  try {
    // Pass 1, the layout as given: what the user sees, the panels' states and the Problems tab.
    const view = await withLogAtEnd({ chromium, url: viewUrl, panels, deadline, consoleErrors, timings, play: true, failShot }, async (page, png, settled) => {
      const shot = path.join(outDir, `${stem}.png`);
      await writeFile(shot, png);
      screenshots.push(shot);
      const { results, dom } = await readPanels(page, panels, png);
      const problems = await readProblems(page, deadline);
      const problemsShot = path.join(outDir, `${stem}-problems.png`);
      await page.screenshot({ path: problemsShot, type: "png" });
      screenshots.push(problemsShot);
      return { results, dom, problems, settled };
    });
    // Pass 2, the probe layout: the Plot series' pixels. Plots draw the whole log from the preloaded
    // blocks, so a seek to the end stands in for a second playback.
    if (view.results.some((r) => r.state === "unmeasured")) {
      await withLogAtEnd({ chromium, url: probeUrl, panels, deadline, consoleErrors, timings, play: false, failShot }, async (page, png) => {
        const shot = path.join(outDir, `${stem}-probe.png`);
        await writeFile(shot, png);
        screenshots.push(shot);
        await measurePlots(page, panels, view.results, png);
      });
    }
    addEmptyTexts(view.results, view.dom);
    return {
      log: logFile,
      opened: true,
      settled: view.settled,
      problems: view.problems,
      panels: view.results,
      screenshots,
      timings,
      consoleErrors: summariseConsole(consoleErrors),
    };
  } catch (error) {
    if (error.shot) {
      screenshots.push(error.shot);
    }
    return {
      log: logFile,
      opened: false,
      failure: error.message,
      problems: [],
      panels: [],
      screenshots,
      consoleErrors: summariseConsole(consoleErrors),
    };
  }
}

function verdict(result) {
  const reasons = [];
  if (!result.opened) {
    reasons.push(`could not check the log: ${result.failure}`);
  }
  if (result.problems.length > 0) {
    reasons.push(`${result.problems.length} Problems entries`);
  }
  for (const panel of result.panels) {
    if (panel.state !== "data") {
      reasons.push(`panel "${panel.title}": ${panel.state}`);
    }
    for (const error of panel.legendErrors ?? []) {
      reasons.push(`panel "${panel.title}" legend: ${error}`);
    }
  }
  return { ok: reasons.length === 0, reasons };
}

function textReport(result) {
  const lines = [`log: ${result.log}`];
  if (!result.opened) {
    lines.push(`  NOT CHECKED: ${result.failure}`);
  } else if (!result.settled) {
    lines.push("  note: the window was still changing 60 s after playback ended; read the screenshots");
  }
  lines.push(`  Problems (${result.problems.length}):`);
  for (const problem of result.problems) {
    lines.push(`    ${problem.message}${problem.details ? `\n      ${problem.details.replace(/\n/g, "\n      ")}` : ""}`);
  }
  lines.push("  Panels:");
  for (const panel of result.panels) {
    lines.push(`    [${panel.state}] ${panel.title} (${panel.id}): ${panel.detail}`);
    for (const series of panel.series ?? []) {
      const error = series.legendError ? `  LEGEND ERROR: ${series.legendError}` : "";
      const alone = series.pixelsAlone != undefined ? `, ${series.pixelsAlone} px alone` : "";
      lines.push(`        ${series.visibility.padEnd(9)} ${series.label} (${series.pixels} px${alone})${error}`);
    }
    for (const row of panel.rows ?? []) {
      if (typeof row === "object") {
        lines.push(`        ${(row.drawn ? "drawn" : "absent").padEnd(9)} ${row.label} (${row.colouredColumns} coloured columns)`);
      }
    }
  }
  lines.push(`  screenshots: ${result.screenshots.join(", ")}`);
  lines.push(`  verdict: ${result.verdict.ok ? "OK" : `FAIL (${result.verdict.reasons.join("; ")})`}`);
  return lines.join("\n");
}

// ------------------------------------------------------------------------------------------------- main

async function main() {
  let options;
  let indexHtml;
  let layout;
  let panels;
  try {
    options = parseArguments(process.argv.slice(2));
    indexHtml = await loadAppIndex(options.appDir);
    ({ layout, panels } = await loadLayout(options.layoutFile));
    const names = new Set();
    for (const file of options.logFiles) {
      await checkLog(file);
      if (names.has(path.basename(file))) {
        throw new UsageError(`--log ${file}: another --log has the same file name (screenshots are named after it)`);
      }
      names.add(path.basename(file));
    }
    await checkChromium(options.chromium);
    await mkdir(options.outDir, { recursive: true }).catch((error) => {
      throw new UsageError(`--out ${options.outDir}: cannot create the directory (${error.message})`);
    });
  } catch (error) {
    if (error instanceof UsageError) {
      process.stderr.write(`viewer_check: ${error.message}\n`);
      return 2;
    }
    throw error;
  }
  const view = await startServer({
    appDir: options.appDir,
    indexHtml: injectLayout(indexHtml, layout),
    logFiles: options.logFiles,
  });
  const probe = await startServer({
    appDir: options.appDir,
    indexHtml: injectLayout(indexHtml, probeLayout(layout)),
    logFiles: options.logFiles,
  });
  const appUrl = (served, logFile) => {
    const url = new URL(`http://127.0.0.1:${served.port}/`);
    url.searchParams.set("ds", "remote-file");
    url.searchParams.set("ds.url", served.logUrls.get(logFile));
    return url.toString();
  };
  const results = [];
  try {
    for (const logFile of options.logFiles) {
      const result = await checkOneLog({
        chromium: options.chromium,
        viewUrl: appUrl(view, logFile),
        probeUrl: appUrl(probe, logFile),
        logFile,
        panels,
        outDir: options.outDir,
        timeoutMs: options.timeoutMs,
      });
      result.layout = options.layoutFile;
      result.verdict = verdict(result);
      results.push(result);
      process.stdout.write(`${textReport(result)}\n`);
    }
  } finally {
    view.server.close();
    probe.server.close();
  }
  const report = path.join(options.outDir, "report.json");
  await writeFile(report, `${JSON.stringify({ app: options.appDir, results }, null, 2)}\n`);
  const ok = results.every((r) => r.verdict.ok);
  process.stdout.write(`report: ${report}\n${ok ? "OK" : "FAIL"}\n`);
  return ok ? 0 : 1;
}

main().then(
  (code) => process.exit(code),
  (error) => {
    process.stderr.write(`viewer_check: ${error.stack ?? error}\n`);
    process.exit(1);
  },
);
