// The rtu2mqtt console: one page, its views chosen by the address's #fragment. Everything it
// shows arrives from the gateway (the model once, the plant view pushed as server-sent events,
// figures on request); everything it changes is an HTTP POST. Text from the gateway is only
// ever set as text, never as markup.
"use strict";

const state = {
  model: null,
  values: new Map(), // topic -> {payload, at_ms}
  events: null,
  frames: null,
  framesPaused: false,
  frameLog: [], // records in the frame recorder's format, for the download
  timer: null,
};
const MAX_FRAME_ROWS = 500;
const MAX_FRAME_LOG = 20000;

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key === "text") node.textContent = value;
    else if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
    else node.setAttribute(key, value === true ? "" : value);
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

function topicOf(device, field) {
  return `${state.model.prefix}/${device}/${field}`;
}

function age(atMs) {
  if (!atMs) return "";
  const seconds = Math.max(0, Math.round((Date.now() - atMs) / 1000));
  if (seconds < 60) return `${seconds} s ago`;
  if (seconds < 3600) return `${Math.floor(seconds / 60)} min ago`;
  return `${Math.floor(seconds / 3600)} h ago`;
}

async function post(path, fields) {
  const body = new URLSearchParams(fields);
  const response = await fetch(path, {
    method: "POST",
    body,
    credentials: "same-origin",
    headers: { "Content-Type": "application/x-www-form-urlencoded" },
  });
  let data = null;
  try { data = await response.json(); } catch (_) { data = null; }
  if (!response.ok) {
    const reason = data && data.error ? data.error : `${response.status} ${response.statusText}`;
    throw new Error(reason);
  }
  return data;
}

async function getJson(path) {
  const response = await fetch(path, { credentials: "same-origin" });
  if (response.status === 401) { location.href = "/login"; throw new Error("log in first"); }
  if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
  return response.json();
}

// The model with each device's fields found in its profile (sent once per profile).
async function loadModel() {
  const model = await getJson("/api/model");
  for (const device of model.devices) {
    const profile = model.profiles[device.profile];
    device.profile_name = profile ? profile.name : "";
    device.fields = profile ? profile.fields : [];
  }
  return model;
}

// ----- the plant view, pushed -----

function connectEvents() {
  if (state.events) state.events.close();
  const live = document.getElementById("live");
  const events = new EventSource("/api/events");
  state.events = events;
  events.addEventListener("snapshot", (event) => {
    state.values.clear();
    for (const message of JSON.parse(event.data)) state.values.set(message.topic, message);
    live.textContent = "live";
    live.className = "badge on";
    refreshAllValues();
  });
  events.addEventListener("publish", (event) => {
    for (const message of JSON.parse(event.data)) {
      if (message.payload === "") state.values.delete(message.topic);
      else state.values.set(message.topic, message);
      showTopic(message.topic);
    }
  });
  events.addEventListener("layout", async () => {
    // The configuration was reloaded: devices may have come or gone.
    try { state.model = await loadModel(); route(); } catch (_) { /* the next event retries */ }
  });
  events.onerror = () => {
    live.textContent = "reconnecting…";
    live.className = "badge off";
  };
}

// The elements showing each topic on the current page, found once per page.
const shown = { values: new Map(), availability: new Map(), outcomes: new Map() };

function indexPage() {
  const index = (map, selector, key) => {
    map.clear();
    for (const node of document.querySelectorAll(selector)) {
      const topic = key(node);
      if (!map.has(topic)) map.set(topic, []);
      map.get(topic).push(node);
    }
  };
  index(shown.values, "[data-topic]", (n) => n.dataset.topic);
  index(shown.availability, "[data-availability]", (n) => n.dataset.availability);
  index(shown.outcomes, "[data-outcome-for]", (n) => n.dataset.outcomeFor.slice(0, -"/set".length) + "/result");
}

function showTopic(topic) {
  const message = state.values.get(topic);
  for (const node of shown.values.get(topic) || []) showValue(node, message);
  for (const node of shown.availability.get(topic) || []) showAvailability(node, message);
  for (const node of shown.outcomes.get(topic) || []) showOutcome(node, message);
}

function refreshAllValues() {
  indexPage();
  for (const node of document.querySelectorAll("[data-topic]")) showValue(node, state.values.get(node.dataset.topic));
  for (const node of document.querySelectorAll("[data-availability]")) showAvailability(node, state.values.get(node.dataset.availability));
  for (const node of document.querySelectorAll("[data-outcome-for]")) {
    const result = node.dataset.outcomeFor.slice(0, -"/set".length) + "/result";
    if (!node.dataset.pending) showOutcome(node, state.values.get(result));
  }
}

function showValue(node, message) {
  node.textContent = message ? message.payload : "–";
  node.dataset.at = message ? message.at_ms : "";
  const when = node.parentElement && node.parentElement.querySelector(".age");
  if (when) when.textContent = message ? age(message.at_ms) : "not read yet";
}

function showAvailability(node, message) {
  const word = message ? message.payload : "unknown";
  node.textContent = word;
  node.className = `badge ${word === "online" ? "on" : "off"}`;
}

function showOutcome(node, message) {
  if (!message) { node.textContent = ""; return; }
  delete node.dataset.pending;
  let text = message.payload;
  try {
    const result = JSON.parse(message.payload);
    text = `${result.outcome}: ${result.detail || ""} (${result.value})`;
    node.className = `outcome ${result.outcome}`;
  } catch (_) { node.className = "outcome"; }
  node.textContent = text;
}

function tickAges() {
  for (const node of [...shown.values.values()].flat()) {
    const when = node.parentElement && node.parentElement.querySelector(".age");
    if (when && node.dataset.at) when.textContent = age(Number(node.dataset.at));
  }
}

// ----- pages -----

function setPage(name, ...content) {
  for (const link of document.querySelectorAll("nav a")) {
    link.classList.toggle("current", link.dataset.page === name);
    if (link.dataset.page === name) link.setAttribute("aria-current", "page");
    else link.removeAttribute("aria-current");
  }
  const page = document.getElementById("page");
  // A page leaves out what it has not got (the plant page's filter below the fold limit).
  page.replaceChildren(...content.filter((part) => part !== null && part !== undefined));
  indexPage();
}

function fieldRow(device, field, withControls) {
  const topic = topicOf(device.name, field.name);
  const value = el("span", { class: "value", "data-topic": topic, text: "–" });
  const cells = [
    el("th", { scope: "row", title: field.description || null, text: field.label }),
    el("td", { class: "reading" }, value, field.unit ? el("span", { class: "unit", text: ` ${field.unit}` }) : null,
      el("div", { class: "age", text: "not read yet" })),
  ];
  if (withControls) {
    cells.push(el("td", { class: "control" }, field.writable ? control(device, field) : null));
  }
  return el("tr", { "data-field": field.name }, cells);
}

function control(device, field) {
  const topic = `${topicOf(device.name, field.name)}/set`;
  const outcome = el("output", { "data-outcome-for": topic, class: "outcome" });
  const send = async (payload) => {
    outcome.dataset.pending = "1";
    outcome.className = "outcome waiting";
    outcome.textContent = `sending ${payload}…`;
    try {
      await post("/api/command", { topic, payload });
      // The outcome may have come already (a quick device): then it stays.
      if (outcome.dataset.pending) outcome.textContent = `${payload}: waiting for the outcome…`;
    } catch (error) {
      delete outcome.dataset.pending;
      outcome.className = "outcome rejected";
      outcome.textContent = `refused: ${error.message}`;
    }
  };
  if (state.model.read_only) {
    return el("span", { class: "hint", text: "read-only console" });
  }
  let input;
  const label = `Set ${field.label}`;
  switch (field.kind) {
    case "bool":
      input = el("span", { class: "buttons" },
        el("button", { type: "button", value: "ON", "data-command-topic": topic, "aria-label": `${field.label} on`, onclick: () => send("ON") }, "ON"),
        el("button", { type: "button", value: "OFF", "data-command-topic": topic, "aria-label": `${field.label} off`, onclick: () => send("OFF") }, "OFF"));
      break;
    case "button":
      input = el("button", { type: "button", value: "PRESS", "data-command-topic": topic, "aria-label": field.label, onclick: () => send("PRESS") }, "Press");
      break;
    case "enum": {
      const select = el("select", { "data-command-topic": topic, "aria-label": label },
        el("option", { value: "", text: "choose…" }),
        field.options.map((word) => el("option", { value: word, text: word })));
      select.addEventListener("change", () => { if (select.value) send(select.value); select.value = ""; });
      input = select;
      break;
    }
    default: {
      const hint = field.min !== null && field.min !== undefined ? `${field.min} – ${field.max}` : "value";
      const box = el("input", {
        type: "text", inputmode: field.kind === "text" ? null : "decimal", "data-command-topic": topic,
        "aria-label": label, placeholder: field.step ? `${hint}, step ${field.step}` : hint, enterkeyhint: "send",
      });
      box.addEventListener("keydown", (event) => {
        if (event.key === "Enter" && box.value.trim() !== "") { event.preventDefault(); send(box.value.trim()); }
      });
      input = box;
    }
  }
  return el("div", { class: "command" }, input, outcome);
}

function deviceCard(device, withControls) {
  const availability = el("span", { class: "badge off", "data-availability": `${state.model.prefix}/${device.name}/availability`, text: "unknown" });
  const title = withControls
    ? el("h2", {}, device.name, " ", availability)
    : el("h2", {}, el("a", { href: `#/device/${encodeURIComponent(device.name)}`, text: device.name }), " ", availability);
  const table = el("table", { class: "fields" },
    el("tbody", {}, device.fields.map((field) => fieldRow(device, field, withControls))));
  return el("section", { class: "card device", "data-device": device.name },
    title,
    el("p", { class: "meta", text: `${device.manufacturer} ${device.model} · line ${device.line}, address ${device.address} · every ${device.poll_interval_ms} ms` }),
    table);
}

// Above this many devices the plant page lists them folded, each drawn when opened: a plant
// of a thousand meters would otherwise be a hundred thousand rows.
const FOLD_ABOVE = 24;

function foldedCard(device) {
  const availability = el("span", { class: "badge off", "data-availability": `${state.model.prefix}/${device.name}/availability`, text: "unknown" });
  const body = el("div");
  const card = el("details", { class: "card device folded", "data-device": device.name },
    el("summary", {}, el("span", { class: "name", text: device.name }), " ", availability,
      el("span", { class: "meta", text: ` ${device.model} · ${device.line}, address ${device.address}` })),
    body);
  card.addEventListener("toggle", () => {
    if (card.open && !body.firstChild) {
      body.append(el("p", {}, el("a", { href: `#/device/${encodeURIComponent(device.name)}`, text: "Open the device" })),
        el("table", { class: "fields" }, el("tbody", {}, device.fields.map((field) => fieldRow(device, field, false)))));
      refreshAllValues();
    }
  });
  return card;
}

function plantPage() {
  const devices = state.model.devices;
  const folded = devices.length > FOLD_ABOVE;
  const filter = folded ? el("input", { type: "search", placeholder: "Find a device", "aria-label": "Find a device" }) : null;
  const cards = devices.map((d) => (folded ? foldedCard(d) : deviceCard(d, false)));
  if (filter) {
    filter.addEventListener("input", () => {
      const wanted = filter.value.trim().toLowerCase();
      for (const card of cards) card.hidden = wanted !== "" && !card.dataset.device.includes(wanted);
    });
  }
  setPage("plant", el("h1", { text: "Plant" }), filter,
    devices.length ? el("div", { class: folded ? "list" : "grid" }, cards)
      : el("p", { text: "No device is configured." }));
  refreshAllValues();
}

function devicePage(name) {
  const device = state.model.devices.find((d) => d.name === name);
  if (!device) { setPage("plant", el("p", { class: "error", text: `No device named ${name}.` })); return; }
  const refreshOutcome = el("output", { class: "outcome" });
  const refresh = el("button", {
    type: "button", onclick: async () => {
      refreshOutcome.textContent = "asking the line…";
      try { await post("/api/refresh", { device: device.name }); refreshOutcome.textContent = "every block is read in the line's next slots"; }
      catch (error) { refreshOutcome.textContent = `refused: ${error.message}`; }
    },
  }, "Refresh");
  setPage("plant", el("p", {}, el("a", { href: "#/plant", text: "← Plant" })),
    deviceCard(device, true), el("p", {}, refresh, " ", refreshOutcome));
  refreshAllValues();
}

const LINE_FIGURES = [
  ["port_open", "link open"], ["bus_load_percent", "bus load %"], ["transactions", "transactions"],
  ["timeouts", "timeouts"], ["crc_errors", "CRC errors"], ["truncated", "truncated answers"],
  ["exceptions", "exceptions"], ["unexpected_answers", "unexpected answers"], ["late_answers", "late answers"],
  ["stray_bytes", "stray bytes"], ["long_gaps", "pauses inside answers"], ["idle_gap_ms", "idle gap before a request (ms, mean)"],
  ["worst_idle_gap_ms", "idle gap, worst (ms)"], ["commands", "commands"], ["command_latency_ms", "last command (ms)"],
  ["client_requests", "served client requests"], ["cache_hits", "answered from cache"], ["client_refusals", "client refusals"],
];

async function linesPage() {
  const body = el("div", { class: "grid" });
  const journal = el("div");
  setPage("lines", el("h1", { text: "Lines" }), body, el("h2", { text: "History journal" }), journal);
  const draw = async () => {
    let stats;
    try { stats = await getJson("/api/stats"); } catch (error) { body.replaceChildren(el("p", { class: "error", text: error.message })); return; }
    body.replaceChildren(...stats.lines.map((line) => {
      const model = state.model.lines.find((l) => l.name === line.line);
      const rows = LINE_FIGURES.map(([key, label]) => el("tr", {}, el("th", { scope: "row", text: label }), el("td", { "data-figure": key, text: line[key] === null || line[key] === undefined ? "–" : String(line[key]) })));
      const devices = Object.entries(line.devices || {}).map(([name, d]) => el("tr", {},
        el("th", { scope: "row", text: name }), el("td", { text: d.online ? "online" : "offline" }),
        el("td", { text: d.latency_ms === null ? "–" : `${d.latency_ms} ms` }), el("td", { text: d.worst_latency_ms === null ? "–" : `${d.worst_latency_ms} ms` }),
        el("td", { text: `${d.timeouts}/${d.crc_errors}/${d.exceptions}` })));
      return el("section", { class: "card", "data-line-stats": line.line },
        el("h2", { text: line.line }), el("p", { class: "meta", text: model ? `${model.link} · ${model.tcp ? "" : `${model.baud} ${model.format}`}` : "" }),
        el("table", { class: "figures" }, el("tbody", {}, rows)),
        el("div", { class: "scroll" }, el("table", { class: "figures" }, el("thead", {}, el("tr", {}, ["device", "state", "latency", "worst", "timeouts / CRC / exc."].map((h) => el("th", { scope: "col", text: h })))), el("tbody", {}, devices))));
    }));
    const history = stats.gateway.history;
    journal.replaceChildren(history ? el("pre", { text: JSON.stringify(history, null, 2) }) : el("p", { text: "No journal: [history] is not configured." }));
  };
  await draw();
  state.timer = setInterval(draw, 2000);
}

function framesPage() {
  const lineSelect = el("select", { id: "frame-line", name: "line", "aria-label": "Line" },
    el("option", { value: "", text: "every line" }), state.model.lines.map((l) => el("option", { value: l.name, text: l.name })));
  const address = el("input", { id: "frame-address", name: "address", type: "text", inputmode: "numeric", placeholder: "any", "aria-label": "Address" });
  const fn = el("input", { id: "frame-function", name: "function", type: "text", inputmode: "numeric", placeholder: "any", "aria-label": "Function" });
  const pause = el("button", { type: "button", "aria-pressed": "false" }, "Pause");
  const clear = el("button", { type: "button" }, "Clear");
  const download = el("button", { type: "button" }, "Download");
  const rows = el("tbody", { id: "frame-rows" });
  const missed = el("p", { class: "hint" });
  pause.addEventListener("click", () => {
    state.framesPaused = !state.framesPaused;
    pause.textContent = state.framesPaused ? "Resume" : "Pause";
    pause.setAttribute("aria-pressed", String(state.framesPaused));
  });
  clear.addEventListener("click", () => { rows.replaceChildren(); state.frameLog = []; });
  download.addEventListener("click", () => {
    const blob = new Blob([state.frameLog.join("\n") + (state.frameLog.length ? "\n" : "")], { type: "text/plain" });
    const link = el("a", { href: URL.createObjectURL(blob), download: "frames.log" });
    document.body.append(link); link.click(); link.remove();
  });
  const wanted = (frame) => {
    const a = address.value.trim(); const f = fn.value.trim();
    if (a && frame.address !== Number(a)) return false;
    if (f && frame.function !== Number(f) && frame.function !== (Number(f) | 0x80)) return false;
    return true;
  };
  const open = () => {
    if (state.frames) state.frames.close();
    const query = lineSelect.value ? `?line=${encodeURIComponent(lineSelect.value)}` : "";
    const source = new EventSource(`/api/frames${query}`);
    state.frames = source;
    source.addEventListener("frame", (event) => {
      const frame = JSON.parse(event.data);
      state.frameLog.push(`${frame.line} ${frame.at} ${frame.dir} ${frame.hex.toUpperCase()}`);
      if (state.frameLog.length > MAX_FRAME_LOG) state.frameLog.shift();
      if (state.framesPaused || !wanted(frame)) return;
      const time = new Date(frame.at_us / 1000);
      const row = el("tr", { "data-line": frame.line, "data-hex": frame.hex, class: frame.exception !== null ? "exception" : frame.dir },
        el("td", { text: `${time.toLocaleTimeString([], { hour12: false })}.${String(time.getMilliseconds()).padStart(3, "0")}` }),
        el("td", { class: "num", text: frame.gap_us === null ? "" : (frame.gap_us / 1000).toFixed(2) }),
        el("td", { text: frame.line }), el("td", { text: frame.dir }),
        el("td", { class: "num", text: frame.address === null ? "" : String(frame.address) }),
        el("td", { class: "num", text: frame.function === null ? "" : String(frame.function) }),
        el("td", { text: frame.summary }), el("td", { class: "hex", text: frame.hex }));
      rows.prepend(row);
      while (rows.children.length > MAX_FRAME_ROWS) rows.lastElementChild.remove();
    });
    source.addEventListener("missed", (event) => { missed.textContent = `${event.data} frames were missed: the page fell behind.`; });
  };
  lineSelect.addEventListener("change", open);
  setPage("frames", el("h1", { text: "Frames" }),
    el("div", { class: "toolbar" },
      el("label", {}, "Line ", lineSelect), el("label", {}, "Address ", address), el("label", {}, "Function ", fn),
      pause, clear, download),
    missed,
    el("div", { class: "scroll" }, el("table", { class: "frames" },
      el("thead", {}, el("tr", {}, ["time", "gap ms", "line", "dir", "addr", "fn", "frame", "hex"].map((h) => el("th", { scope: "col", text: h })))),
      rows)));
  open();
}

function lineChoice(id) {
  return el("select", { id, name: "line", required: true },
    state.model.lines.map((l) => el("option", { value: l.name, text: `${l.name} (${l.link})` })));
}

function commissionPage() {
  const scanResult = el("div", { id: "scan-result" });
  const scanForm = el("form", { "data-form": "scan", class: "card full" },
    el("h2", { text: "Scan" }),
    el("p", { class: "hint", text: "Reads one register at each address through the running line, between its polls, and asks each device found what it is." }),
    el("label", { for: "scan-line" }, "Line"), lineChoice("scan-line"),
    el("label", { for: "scan-addresses" }, "Addresses (1-5,129)"),
    el("input", { id: "scan-addresses", name: "addresses", type: "text", value: "1-10", required: true }),
    el("button", { type: "submit" }, "Scan"), scanResult);
  scanForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    scanResult.replaceChildren(el("p", { text: "scanning…" }));
    try {
      const report = await post("/api/scan", Object.fromEntries(new FormData(scanForm)));
      const said = ["fc43", "vendor", "product_code", "revision", "sunspec", "profile"];
      const rows = report.found.map((found) => el("tr", { "data-address": String(found.address) },
        el("td", { class: "num", text: String(found.address) }), el("td", { text: `0x${found.address.toString(16).padStart(2, "0")}` }),
        el("td", { class: "answers", text: found.answers.join(", ") }), el("td", { text: found.device || "not configured" }),
        said.map((key) => el("td", { "data-identification": key, text: found.identification[key] || "-" }))));
      const configuration = report.configuration
        ? [el("h3", { text: "To add to the configuration" }), el("pre", { id: "scan-configuration", text: report.configuration })]
        : [];
      scanResult.replaceChildren(el("p", { text: `${report.found.length} of ${report.scanned} addresses answered on ${report.line}.` }),
        el("div", { class: "scroll" }, el("table", { class: "identification" }, el("thead", {}, el("tr", {},
          ["address", "hex", "answers", "device", "FC43", "vendor", "product code", "revision", "SunSpec", "profile"].map((h) => el("th", { scope: "col", text: h })))),
          el("tbody", {}, rows))),
        ...configuration);
    } catch (error) { scanResult.replaceChildren(el("p", { class: "error", text: error.message })); }
  });

  const readResult = el("div", { id: "read-result" });
  const order = el("select", { id: "read-order", "aria-label": "Byte order" }, ["ABCD", "CDAB", "BADC", "DCBA"].map((o) => el("option", { value: o, text: o })));
  let lastRead = null;
  const drawRead = () => {
    if (!lastRead) return;
    if (lastRead.exception) { readResult.replaceChildren(el("p", { class: "error", text: lastRead.exception })); return; }
    if (lastRead.bits) {
      readResult.replaceChildren(el("p", { text: lastRead.request }), el("p", { class: "hex", text: lastRead.bits.map((b) => (b ? "1" : "0")).join("") }));
      return;
    }
    const table = lastRead.registers;
    const rows = table.registers.map((r) => {
      const wide = r.wide.find((w) => w.order === order.value) || {};
      const show = (v) => (v === null || v === undefined ? "" : String(v));
      return el("tr", { "data-register": String(r.address) },
        el("td", { class: "num", text: `${r.address} (0x${r.address.toString(16).padStart(4, "0")})` }), el("td", { class: "hex", text: r.hex }),
        el("td", { class: "num", text: String(r.u16) }), el("td", { class: "num", text: String(r.i16) }), el("td", { class: "hex", text: r.bits }),
        el("td", { class: "num", text: show(wide.u32) }), el("td", { class: "num", text: show(wide.i32) }), el("td", { class: "num", text: show(wide.f32) }),
        el("td", { class: "num", text: show(wide.u64) }), el("td", { class: "num", text: show(wide.i64) }), el("td", { class: "num", text: show(wide.f64) }),
        el("td", { text: r.chars }));
    });
    readResult.replaceChildren(el("p", { text: lastRead.request }),
      el("div", { class: "scroll" }, el("table", {}, el("thead", {}, el("tr", {}, ["register", "hex", "u16", "i16", "bits", "u32", "i32", "f32", "u64", "i64", "f64", "chars"].map((h) => el("th", { scope: "col", text: h })))), el("tbody", {}, rows))),
      el("p", { text: `text, high byte first: "${table.text_high_first}"` }), el("p", { text: `text, low byte first: "${table.text_low_first}"` }));
  };
  order.addEventListener("change", drawRead);
  const readForm = el("form", { "data-form": "read", class: "card" },
    el("h2", { text: "Read registers" }),
    el("label", { for: "read-line" }, "Line"), lineChoice("read-line"),
    el("label", { for: "read-address" }, "Device address"), el("input", { id: "read-address", name: "address", type: "text", inputmode: "numeric", value: "1", required: true }),
    el("label", { for: "read-function" }, "Function"),
    el("select", { id: "read-function", name: "function" },
      el("option", { value: "3", text: "03 holding registers" }), el("option", { value: "4", text: "04 input registers" }),
      el("option", { value: "1", text: "01 coils" }), el("option", { value: "2", text: "02 discrete inputs" })),
    el("label", { for: "read-start" }, "First register (bus address, 0-based; 0x… for hex)"), el("input", { id: "read-start", name: "start", type: "text", value: "0", required: true }),
    el("label", { for: "read-count" }, "Count"), el("input", { id: "read-count", name: "count", type: "number", min: "1", max: "125", value: "8", required: true }),
    el("label", { for: "read-order" }, "Byte order of 32 and 64 bits"), order,
    el("button", { type: "submit" }, "Read"), readResult);
  readForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    readResult.replaceChildren(el("p", { text: "reading…" }));
    try { lastRead = await post("/api/read", Object.fromEntries(new FormData(readForm))); drawRead(); }
    catch (error) { readResult.replaceChildren(el("p", { class: "error", text: error.message })); }
  });

  const tryResult = el("div", { id: "tryout-result" });
  const profile = el("textarea", { id: "tryout-profile", name: "profile", rows: "12", spellcheck: "false", required: true, placeholder: "name = \"my-meter\"\n…" });
  const upload = el("input", { id: "tryout-file", type: "file", accept: ".toml,text/plain" });
  upload.addEventListener("change", async () => { if (upload.files[0]) profile.value = await upload.files[0].text(); });
  const tryForm = el("form", { "data-form": "tryout", class: "card" },
    el("h2", { text: "Try a profile" }),
    el("p", { class: "hint", text: "Checks the profile and reads its blocks once from the device. The running configuration is not touched." }),
    el("label", { for: "tryout-line" }, "Line"), lineChoice("tryout-line"),
    el("label", { for: "tryout-address" }, "Device address"), el("input", { id: "tryout-address", name: "address", type: "text", inputmode: "numeric", value: "1", required: true }),
    el("label", { for: "tryout-profile" }, "Profile (TOML)"), profile,
    el("label", { for: "tryout-file" }, "…or upload the file"), upload,
    el("button", { type: "submit" }, "Try"), tryResult);
  tryForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    tryResult.replaceChildren(el("p", { text: "checking and reading…" }));
    try {
      const report = await post("/api/tryout", Object.fromEntries(new FormData(tryForm)));
      if (!report.valid) {
        tryResult.replaceChildren(el("p", { class: "error", text: "The profile is not valid:" }),
          el("ul", { class: "problems" }, report.problems.map((p) => el("li", { text: p }))));
        return;
      }
      const rows = report.fields.map((f) => el("tr", { "data-field": f.field },
        el("th", { scope: "row", text: f.label }), el("td", { class: "value", text: f.value === null ? "" : f.value }),
        el("td", { text: f.unit || "" }), el("td", { text: f.block }), el("td", { class: "error", text: f.error || "" })));
      tryResult.replaceChildren(el("p", { text: `${report.name}: valid; ${report.fields.length} fields read.` }),
        el("table", {}, el("thead", {}, el("tr", {}, ["field", "value", "unit", "block", "problem"].map((h) => el("th", { scope: "col", text: h })))), el("tbody", {}, rows)));
    } catch (error) { tryResult.replaceChildren(el("p", { class: "error", text: error.message })); }
  });
  setPage("commission", el("h1", { text: "Commission" }), el("div", { class: "grid wide" }, scanForm, readForm, tryForm));
}

async function gatewayPage() {
  const body = el("div");
  setPage("gateway", el("h1", { text: "Gateway" }), body);
  const draw = async () => {
    let info, stats;
    try { [info, stats] = await Promise.all([getJson("/api/gateway"), getJson("/api/stats")]); }
    catch (error) { body.replaceChildren(el("p", { class: "error", text: error.message })); return; }
    const g = stats.gateway;
    const rows = [
      ["version", info.version], ["uptime", `${info.uptime_s} s`],
      ["MQTT", info.mqtt_connected ? "connected" : "not connected"], ["status", info.status || "–"],
      ["devices online", `${g.devices_online} of ${g.devices_total}`], ["lines open", `${g.lines_open} of ${g.lines_total}`],
      ["published", g.mqtt.published], ["commands waiting", g.commands.waiting],
      ["commands applied / rejected / failed", `${g.commands.applied} / ${g.commands.rejected} / ${g.commands.failed}`],
      ["history journal", info.history_problem ? `cannot be written: ${info.history_problem}` : (g.history ? "writing" : "not configured")],
      ["bridge loop", `turned ${info.bridge_heartbeat_ms} ms ago`],
    ];
    body.replaceChildren(
      el("section", { class: "card" }, el("table", { class: "figures" }, el("tbody", {}, rows.map(([k, v]) => el("tr", {}, el("th", { scope: "row", text: k }), el("td", { text: String(v) })))))),
      el("section", { class: "card" }, el("h2", { text: "Configuration in effect (secrets masked)" }), el("pre", { id: "effective-config", text: JSON.stringify(info.config, null, 2) })));
  };
  await draw();
  state.timer = setInterval(draw, 2000);
}

function route() {
  if (state.timer) { clearInterval(state.timer); state.timer = null; }
  if (state.frames && !location.hash.startsWith("#/frames")) { state.frames.close(); state.frames = null; }
  const [, page, arg] = (location.hash || "#/plant").split("/");
  switch (page) {
    case "device": devicePage(decodeURIComponent(arg || "")); break;
    case "lines": linesPage(); break;
    case "frames": framesPage(); break;
    case "commission": commissionPage(); break;
    case "gateway": gatewayPage(); break;
    default: plantPage();
  }
}

async function start() {
  try { state.model = await loadModel(); }
  catch (error) { document.getElementById("page").replaceChildren(el("p", { class: "error", text: `The gateway did not answer: ${error.message}` })); return; }
  document.getElementById("gateway-id").textContent = state.model.gateway_id;
  document.getElementById("logout").hidden = state.model.read_only;
  window.addEventListener("hashchange", route);
  connectEvents();
  route();
  setInterval(tickAges, 1000);
}

document.addEventListener("DOMContentLoaded", start);
