#!/usr/bin/env python3
"""Browser test of the interactive replay (experiments/replay.h) in headless Chromium.

Runs a small `omnicml compare` into a directory whose name holds markup, opens its
replay.html in headless Chromium driven over the DevTools protocol (python3-websocket),
moves the slider with real key presses and by script, and checks what the page drew
(window.replayState and the canvases' pixels) against the run's own files: the number of
reference views alive at the slider's frame by events.csv, the frame from frames.csv.
Fails on any console error or uncaught exception; checks that the directory name's markup
stays text. Exit 77 (skipped) when chromium or the websocket module is missing.
Usage: replay_browser_test.py OMNICML_BINARY
"""
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request

SKIP = 77


def find_chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class DevTools:
    """A minimal DevTools protocol client on one page target."""

    def __init__(self, ws_url, websocket):
        self.ws = websocket.create_connection(ws_url, timeout=60, suppress_origin=True)
        self.next_id = 0
        self.events = []

    def call(self, method, **params):
        self.next_id += 1
        my_id = self.next_id
        self.ws.send(json.dumps({"id": my_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            self.events.append(msg)

    def wait_event(self, method, timeout_s=60):
        deadline = time.time() + timeout_s
        for i, e in enumerate(self.events):
            if e.get("method") == method:
                return self.events.pop(i)
        while time.time() < deadline:
            msg = json.loads(self.ws.recv())
            if msg.get("method") == method:
                return msg
            self.events.append(msg)
        raise RuntimeError(f"no {method} within {timeout_s} s")

    def evaluate(self, expression):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                      awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails']}")
        return r["result"].get("value")

    def drain(self):
        self.ws.settimeout(0.5)
        try:
            while True:
                self.events.append(json.loads(self.ws.recv()))
        except Exception:
            pass
        self.ws.settimeout(60)

    def errors(self):
        out = []
        for e in self.events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.exceptionThrown":
                out.append(f"exception: {p['exceptionDetails'].get('text')} "
                           f"{p['exceptionDetails'].get('exception', {}).get('description')}")
            elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append(f"console.{p['type']}: {[a.get('value') for a in p.get('args', [])]}")
            elif m == "Log.entryAdded" and p["entry"].get("level") == "error":
                out.append(f"log: {p['entry'].get('text')} {p['entry'].get('url', '')}")
        return out


def alive_views(events_csv, frame):
    """Views inserted at or before `frame` and not removed by then (by the event log)."""
    born, died = {}, {}
    with open(events_csv, newline="") as f:
        for row in csv.DictReader(f):
            v = row["view_id"]
            if row["type"] == "view_inserted":
                born[v] = int(row["frame"])
            elif row["type"] == "view_removed":
                died[v] = int(row["frame"])
            else:
                born.setdefault(v, -1)
    return sum(1 for v, b in born.items() if b <= frame and not (v in died and died[v] <= frame))


def main():
    binary = sys.argv[1]
    chromium = find_chromium()
    if chromium is None:
        print("SKIPPED: chromium is not installed (Debian package chromium)")
        return SKIP
    try:
        import websocket  # python3-websocket
    except ImportError:
        print("SKIPPED: the Python websocket module is missing (Debian package python3-websocket)")
        return SKIP

    tmp = tempfile.mkdtemp(prefix="omnicml_replay_test_")
    browser = None
    try:
        out = os.path.join(tmp, "cmp <i>x</i> & 'q'")
        r = subprocess.run([binary, "compare", "--world", "home_store", "--days", "2",
                            "--frames-per-day", "40", "--seed", "1", "--steps", "20,40,80",
                            "--quiet", "--jobs", "1", "--out", out], capture_output=True, text=True)
        if r.returncode != 0:
            print(r.stdout, r.stderr)
            return 1
        page = os.path.join(out, "replay.html")
        if not os.path.isfile(page):
            print("compare wrote no replay.html:", r.stdout)
            return 1
        with open(page, encoding="utf-8") as f:
            html = f.read()
        if "<script src" in html or "http://" in html or "https://" in html:
            print("the replay page refers to something outside itself")
            return 1

        profile = os.path.join(tmp, "profile")
        os.makedirs(profile)
        browser = subprocess.Popen(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--user-data-dir=" + profile, "--remote-debugging-port=0",
             "--remote-allow-origins=*", "--window-size=1400,1000", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = os.path.join(profile, "DevToolsActivePort")
        deadline = time.time() + 60
        while not (os.path.exists(port_file) and open(port_file).read().strip()):
            if time.time() > deadline or browser.poll() is not None:
                print("chromium did not start its DevTools server")
                return 1
            time.sleep(0.1)
        port = int(open(port_file).read().split()[0])
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list"))
        target = next(t for t in targets if t.get("type") == "page")
        dt = DevTools(target["webSocketDebuggerUrl"], websocket)
        dt.call("Runtime.enable")
        dt.call("Log.enable")
        dt.call("Page.enable")
        dt.call("Page.navigate", url="file://" + urllib.request.pathname2url(page))
        dt.wait_event("Page.loadEventFired")

        failures = []
        state = dt.evaluate("JSON.stringify(window.replayState)")
        if state is None:
            print("window.replayState is missing; console:", dt.errors())
            return 1
        state = json.loads(state)
        names = [r["name"] for r in state["runs"]]
        if names != ["passive", "active", "static"]:
            failures.append(f"runs {names}")
        if state["index"] != 0:
            failures.append(f"initial index {state['index']}")

        # The directory name's markup stays text.
        title = dt.evaluate("document.getElementById('title').textContent")
        if "<i>x</i>" not in (title or "") or dt.evaluate("document.querySelectorAll('i').length") != 0:
            failures.append(f"title not escaped: {title!r}")

        # Real key presses on the focused slider: End moves it to the last frame.
        dt.evaluate("document.getElementById('slider').focus()")
        for kind in ("rawKeyDown", "keyUp"):
            dt.call("Input.dispatchKeyEvent", type=kind, key="End", code="End",
                    windowsVirtualKeyCode=35, nativeVirtualKeyCode=35)
        s_end = json.loads(dt.evaluate("JSON.stringify(window.replayState)"))
        n_max = int(dt.evaluate("Number(document.getElementById('slider').max)"))
        if s_end["index"] != n_max or s_end["redraws"] <= state["redraws"]:
            failures.append(f"End key: index {s_end['index']} of {n_max}, "
                            f"redraws {state['redraws']} -> {s_end['redraws']}")

        # Then to 60 % by script (an input event, as a drag sends).
        s = json.loads(dt.evaluate(
            "(() => { const s = document.getElementById('slider');"
            " s.value = Math.round(0.6 * Number(s.max)); s.dispatchEvent(new Event('input'));"
            " return JSON.stringify(window.replayState); })()"))
        frames = [row for row in csv.DictReader(open(os.path.join(out, "passive", "frames.csv")))]
        if s["frame"] != int(frames[s["index"]]["global_frame"]):
            failures.append(f"frame {s['frame']} != frames.csv row {s['index']}")
        if s["session"] != int(frames[s["index"]]["session"]):
            failures.append(f"session {s['session']} at index {s['index']}")
        for run in s["runs"]:
            expected = alive_views(os.path.join(out, run["name"], "events.csv"), s["frame"])
            if run["views"] != expected:
                failures.append(f"{run['name']}: {run['views']} views drawn, events.csv says {expected}")
            if run["views"] == 0:
                failures.append(f"{run['name']}: no view drawn at frame {s['frame']}")
        # Something is drawn: map canvases and the plots are not blank.
        inked = dt.evaluate(
            "Array.from(document.querySelectorAll('canvas')).map(c => {"
            " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;"
            " for (let i = 0; i < d.length; i += 4) if (d[i] < 200 || d[i+1] < 200 || d[i+2] < 200) n++;"
            " return n; })")
        if len(inked) != 4 or min(inked) < 200:
            failures.append(f"canvases (3 maps + plots) with too few drawn pixels: {inked}")
        # A click on the plots moves the slider there.
        rect = json.loads(dt.evaluate(
            "JSON.stringify(document.getElementById('chart').getBoundingClientRect())"))
        dt.evaluate("document.getElementById('chart').scrollIntoView()")
        rect = json.loads(dt.evaluate(
            "JSON.stringify(document.getElementById('chart').getBoundingClientRect())"))
        x, y = rect["left"] + 62, rect["top"] + 80  # just right of the plots' left edge
        for kind in ("mousePressed", "mouseReleased"):
            dt.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)
        s_click = json.loads(dt.evaluate("JSON.stringify(window.replayState)"))
        if s_click["index"] > 2:
            failures.append(f"click at the start of the plots gave index {s_click['index']}")

        dt.drain()
        errors = dt.errors()
        if errors:
            failures.append(f"console errors: {errors}")
        for f in failures:
            print("FAIL:", f)
        print(f"replay: {n_max + 1} positions; at index {s['index']} (frame {s['frame']}): "
              + ", ".join(f"{r['name']} {r['views']} views" for r in s["runs"])
              + f"; canvases inked {inked}; {'ok' if not failures else 'FAILED'}")
        return 1 if failures else 0
    finally:
        if browser is not None:
            browser.terminate()
            try:
                browser.wait(timeout=20)
            except subprocess.TimeoutExpired:
                browser.kill()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
