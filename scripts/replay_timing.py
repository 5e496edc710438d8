#!/usr/bin/env python3
"""Times the interactive replay in headless Chromium: page size, load time, and the
redraw time of 100 slider positions spread over the run (median / p95 / max, ms, by
performance.now() around each input event). Needs chromium and python3-websocket.
Usage: replay_timing.py DIR/replay.html
"""
import json, os, subprocess, sys, tempfile, time, urllib.request
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "experiments"))
import websocket
from replay_browser_test import DevTools
page = os.path.abspath(sys.argv[1])
tmp = tempfile.mkdtemp()
b = subprocess.Popen(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--user-data-dir=" + tmp,
    "--remote-debugging-port=0", "--remote-allow-origins=*", "--window-size=1400,1000", "about:blank"],
    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
pf = os.path.join(tmp, "DevToolsActivePort")
while not (os.path.exists(pf) and open(pf).read().strip()): time.sleep(0.1)
port = int(open(pf).read().split()[0])
t = next(t for t in json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list")) if t["type"] == "page")
dt = DevTools(t["webSocketDebuggerUrl"], websocket)
dt.call("Runtime.enable"); dt.call("Page.enable")
t0 = time.time()
dt.call("Page.navigate", url="file://" + page)
dt.wait_event("Page.loadEventFired")
load = time.time() - t0
r = dt.evaluate("""(() => { const s = document.getElementById('slider'); const n = Number(s.max);
  const t = []; for (let k = 0; k < 100; k++) { s.value = Math.round(k / 99 * n);
  const a = performance.now(); s.dispatchEvent(new Event('input')); t.push(performance.now() - a); }
  t.sort((x, y) => x - y); return JSON.stringify({n: n + 1, median: t[50], p95: t[95], max: t[99],
  runs: window.replayState.runs.map(r => r.views)}); })()""")
print(f"{page}: {os.path.getsize(page)/1e6:.2f} MB, load {load:.2f} s, redraw ms {r}, errors {dt.errors()}")
b.terminate(); b.wait()
