// Runs the report page's scripts against a stub DOM (no browser): moves the time slider to the instant
// given (default: the last) and prints the status attributes, the slider and the errors as JSON. Used by test_rig_report.py.
const fs = require("fs");
const html = fs.readFileSync(process.argv[2], "utf8");
const data = html.match(/<script type="application\/json" id="mvm-data">([\s\S]*?)<\/script>/)[1];
const scripts = [...html.matchAll(/<script>([\s\S]*?)<\/script>/g)].map(m => m[1]);
function element(id) {
  const attrs = {}; const listeners = {};
  return {id, attrs, listeners, textContent: id === "mvm-data" ? data : "", value: "0", max: "0", checked: false,
    clientWidth: 800, clientHeight: 500, width: 0, height: 0,
    setAttribute(k, v) { attrs[k] = v; }, getAttribute(k) { return attrs[k]; },
    addEventListener(k, f) { listeners[k] = f; }, setPointerCapture() {},
    getBoundingClientRect() { return {left: 0, top: 0, width: 800, height: 500}; },
    getContext() { return new Proxy({}, {get: (t, k) => (k in t ? t[k] : () => {}), set: (t, k, v) => { t[k] = v; return true; }}); }};
}
const els = {};
global.document = {getElementById: id => (els[id] = els[id] || element(id)), querySelectorAll: () => []};
global.window = {devicePixelRatio: 1, scrollX: 0, scrollY: 0, addEventListener() {}, requestAnimationFrame(f) { f(); },
  setInterval() { return 1; }, clearInterval() {}};
global.performance = {now: () => 1};
global.console = console;
window.mvmErrors = [];
for (const s of scripts) { eval(s); }
const slider = els["mvm-time"];
if (slider && slider.listeners.input) { slider.value = process.argv[3] || slider.max; slider.listeners.input(); }
console.log(JSON.stringify({status: els["mvm-status"].attrs, max: slider && slider.max, label: els["mvm-time-label"] && els["mvm-time-label"].textContent, errors: window.mvmErrors}));
