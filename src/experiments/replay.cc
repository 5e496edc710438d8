#include "omnicml/experiments/replay.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <sstream>
#include <string_view>

#include <nlohmann/json.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/report/svg_plot.h"
#include "omnicml/run/floor_plan.h"
#include "omnicml/run/run_config.h"

namespace omnicml {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

// A number rounded to `decimals`, or null when not finite.
json Round(double v, int decimals) {
  if (!std::isfinite(v)) return nullptr;
  const double f = std::pow(10.0, decimals);
  return std::round(v * f) / f;
}

// Splits one CSV line; quoted cells may hold commas and doubled quotes.
std::vector<std::string> SplitQuotedCsv(const std::string& line) {
  std::vector<std::string> cells(1);
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        cells.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        cells.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      cells.emplace_back();
    } else if (c != '\r') {
      cells.back() += c;
    }
  }
  return cells;
}

MapEventType EventTypeFromString(const std::string& s, const std::string& where) {
  for (MapEventType t :
       {MapEventType::kViewInserted, MapEventType::kViewRemoved, MapEventType::kComponentAdded,
        MapEventType::kComponentMerged, MapEventType::kComponentRemoved}) {
    if (ToString(t) == s) return t;
  }
  throw Error(StrCat(where, ": unknown event type '", Excerpt(s), "'"));
}

double ParseDouble(const std::string& s, const std::string& where, const char* column) {
  if (s.empty()) return kNaN;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0')
    throw Error(StrCat(where, ": ", column, " '", Excerpt(s), "' is not a number"));
  return v;
}

std::int64_t ParseInt(const std::string& s, const std::string& where, const char* column) {
  char* end = nullptr;
  const long long v = std::strtoll(s.c_str(), &end, 10);
  if (s.empty() || *end != '\0')
    throw Error(StrCat(where, ": ", column, " '", Excerpt(s), "' is not an integer"));
  return v;
}

// Indices of the records kept: evenly spaced, plus every day's first frame and the last.
std::vector<std::size_t> SampleIndices(const std::vector<FrameRecord>& records, int max_samples) {
  const std::size_t n = records.size();
  std::vector<std::size_t> out;
  if (n == 0) return out;
  if (n <= static_cast<std::size_t>(max_samples)) {
    for (std::size_t i = 0; i < n; ++i) out.push_back(i);
    return out;
  }
  const std::size_t target = static_cast<std::size_t>(max_samples);
  for (std::size_t k = 0; k < target; ++k) out.push_back(k * (n - 1) / (target - 1));
  for (std::size_t i = 1; i < n; ++i) {
    if (records[i].session != records[i - 1].session) out.push_back(i);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

json FramesJson(const std::vector<FrameRecord>& records, const std::vector<std::size_t>& keep) {
  json f = json::object();
  for (const char* k :
       {"f", "s", "tx", "ty", "tp", "ex", "ey", "ep", "cxx", "cxy", "cyy", "v", "e", "o"})
    f[k] = json::array();
  for (std::size_t i : keep) {
    const FrameRecord& r = records[i];
    f["f"].push_back(r.global_frame);
    f["s"].push_back(r.session);
    f["tx"].push_back(r.has_truth ? Round(r.truth.x(), 3) : json(nullptr));
    f["ty"].push_back(r.has_truth ? Round(r.truth.y(), 3) : json(nullptr));
    f["tp"].push_back(r.has_truth ? Round(r.truth.z(), 3) : json(nullptr));
    f["ex"].push_back(r.has_estimate ? Round(r.estimate.x(), 3) : json(nullptr));
    f["ey"].push_back(r.has_estimate ? Round(r.estimate.y(), 3) : json(nullptr));
    f["ep"].push_back(r.has_estimate ? Round(r.estimate.z(), 3) : json(nullptr));
    f["cxx"].push_back(r.has_estimate ? Round(r.cov_xx_m2, 6) : json(nullptr));
    f["cxy"].push_back(r.has_estimate ? Round(r.cov_xy_m2, 6) : json(nullptr));
    f["cyy"].push_back(r.has_estimate ? Round(r.cov_yy_m2, 6) : json(nullptr));
    f["v"].push_back(r.views);
    f["e"].push_back(Round(r.position_error_m, 3));
    f["o"].push_back(Round(r.odometry_error_m, 3));
  }
  return f;
}

// Views from the event log: position, frame inserted (-1 = before the run), frame
// removed (-1 = still there) and why (1 = active forgetting, 0 = otherwise); component
// removals as (frame, view index), thinned to max_weakening.
json ViewsJson(const std::vector<MapEvent>& events, int max_weakening) {
  std::map<std::uint64_t, std::size_t> index;
  json id = json::array(), x = json::array(), y = json::array(), born = json::array(),
       died = json::array(), why = json::array();
  auto view = [&](const MapEvent& e) {
    auto it = index.find(e.view_id);
    if (it != index.end()) return it->second;
    const std::size_t k = index.size();
    index.emplace(e.view_id, k);
    id.push_back(e.view_id);
    x.push_back(Round(e.position.x(), 3));
    y.push_back(Round(e.position.y(), 3));
    born.push_back(e.type == MapEventType::kViewInserted ? e.frame : -1);
    died.push_back(-1);
    why.push_back(0);
    return k;
  };
  std::vector<std::pair<std::int64_t, std::size_t>> weak;
  std::vector<char> last_loss_active;  // per view: its latest component removal was active
  for (const MapEvent& e : events) {
    switch (e.type) {
      case MapEventType::kViewInserted:
        view(e);
        break;
      case MapEventType::kViewRemoved: {
        const std::size_t k = view(e);
        last_loss_active.resize(index.size(), 0);
        died[k] = e.frame;
        // A view goes when its last component goes: that removal tells why.
        why[k] = IsActiveForgettingReason(e.reason) || last_loss_active[k] ? 1 : 0;
        break;
      }
      case MapEventType::kComponentRemoved: {
        const std::size_t k = view(e);
        last_loss_active.resize(index.size(), 0);
        weak.emplace_back(e.frame, k);
        last_loss_active[k] = IsActiveForgettingReason(e.reason) ? 1 : 0;
        break;
      }
      default:
        break;
    }
  }
  std::stable_sort(weak.begin(), weak.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  json wf = json::array(), wv = json::array();
  const std::size_t n = weak.size();
  const std::size_t keep = std::min(n, static_cast<std::size_t>(std::max(0, max_weakening)));
  for (std::size_t k = 0; k < keep; ++k) {
    const auto& [frame, v] = weak[keep == n ? k : k * n / keep];
    wf.push_back(frame);
    wv.push_back(v);
  }
  return {{"views", {{"id", id}, {"x", x}, {"y", y}, {"born", born}, {"died", died}, {"why", why}}},
          {"weak", {{"f", wf}, {"v", wv}, {"total", n}}}};
}

json PlanJson(const FloorPlan& plan) {
  json walls = json::array(), blocks = json::array(), boxes = json::array();
  for (const FloorPlanShape& s : plan.shapes) {
    json pts = json::array();
    for (const auto& p : s.points_m) {
      pts.push_back(Round(p.x(), 3));
      pts.push_back(Round(p.y(), 3));
    }
    if (s.kind == FloorPlanShape::Kind::kWall) {
      if (s.closed && !s.points_m.empty()) {
        pts.push_back(Round(s.points_m.front().x(), 3));
        pts.push_back(Round(s.points_m.front().y(), 3));
      }
      walls.push_back(pts);
    } else {
      (s.kind == FloorPlanShape::Kind::kBox ? boxes : blocks).push_back(pts);
    }
  }
  return {{"name", plan.name}, {"walls", walls}, {"blocks", blocks}, {"boxes", boxes}};
}

// JSON text safe inside <script>: <, > and & only occur in strings, where \u escapes
// keep their meaning.
std::string ScriptSafeJson(const json& j) {
  const std::string text = j.dump(-1, ' ', false, json::error_handler_t::replace);
  std::string out;
  out.reserve(text.size() + 64);
  for (char c : text) {
    if (c == '<') {
      out += "\\u003c";
    } else if (c == '>') {
      out += "\\u003e";
    } else if (c == '&') {
      out += "\\u0026";
    } else {
      out += c;
    }
  }
  return out;
}

// The page's style and script (fixed text; the data comes as JSON).
constexpr std::string_view kStyle = R"CSS(
body{font-family:sans-serif;margin:0.6em 1em;color:#222}
h1{font-size:1.2em;margin:0.2em 0}
#input{color:#555;font-size:0.9em}
#controls{display:flex;align-items:center;gap:0.8em;margin:0.5em 0;flex-wrap:wrap}
#slider{flex:1;min-width:300px}
#label{font-variant-numeric:tabular-nums;min-width:16em}
#panels{display:flex;flex-wrap:wrap;gap:8px}
.panel{border:1px solid #ddd;padding:4px}
.panel h2{font-size:1em;margin:0 0 2px 0}
.panel .counts{font-size:0.8em;color:#444;font-variant-numeric:tabular-nums}
#legend{font-size:0.8em;color:#444;margin:4px 0;display:flex;flex-wrap:wrap;gap:2px 1.2em}
#legend span{white-space:nowrap}
#chart{border:1px solid #ddd;cursor:crosshair;margin-top:6px}
#note{font-size:0.8em;color:#666}
)CSS";

constexpr std::string_view kScript = R"JS(
"use strict";
(function () {
  const D = JSON.parse(document.getElementById("replay-data").textContent);
  const runColors = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00"];
  document.title = D.title;
  document.getElementById("title").textContent = D.title;
  document.getElementById("input").textContent = D.input;
  const runs = D.runs;
  const base = runs[0].frames;
  const nSamples = base.f.length;
  const totalFrames = base.f[nSamples - 1] - base.f[0] + 1;
  const flashFrames = Math.max(5, Math.round(totalFrames / 150));
  const slider = document.getElementById("slider");
  slider.min = 0;
  slider.max = nSamples - 1;
  slider.value = 0;
  // "#at=0.6" in the address opens the replay 60 % of the way through.
  const at = /[#&]at=([0-9.]+)/.exec(window.location.hash);
  if (at) slider.value = Math.round(Math.min(1, parseFloat(at[1])) * (nSamples - 1));
  document.getElementById("note").textContent =
    "Slider: " + nSamples + " of " + D.frames_total + " frames" +
    (nSamples < D.frames_total ? " (evenly spaced, every day's first frame kept)" : "") +
    ". Views come from the event log at the frame whose observation caused the change " +
    "(updates are applied update_delay_frames later, so the map-size curve lags by that). " +
    "Crosses and rings stay " + flashFrames + " frames. Click or drag on the plots to move.";

  // Bounding box of everything drawn on the maps.
  let lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
  function ext(x, y) {
    if (x === null || y === null || !isFinite(x) || !isFinite(y)) return;
    lo[0] = Math.min(lo[0], x); lo[1] = Math.min(lo[1], y);
    hi[0] = Math.max(hi[0], x); hi[1] = Math.max(hi[1], y);
  }
  for (const group of [D.plan.walls, D.plan.blocks, D.plan.boxes])
    for (const pts of group) for (let i = 0; i + 1 < pts.length; i += 2) ext(pts[i], pts[i + 1]);
  for (const r of runs) {
    const f = r.frames;
    for (let i = 0; i < f.f.length; i++) { ext(f.tx[i], f.ty[i]); ext(f.ex[i], f.ey[i]); }
    for (let i = 0; i < r.views.x.length; i++) ext(r.views.x[i], r.views.y[i]);
  }
  if (!isFinite(lo[0])) { lo = [0, 0]; hi = [1, 1]; }
  const pad = 0.03 * Math.max(hi[0] - lo[0], hi[1] - lo[1], 1);
  lo = [lo[0] - pad, lo[1] - pad]; hi = [hi[0] + pad, hi[1] + pad];
  const avail = Math.max(320, Math.min(900, (window.innerWidth - 60) / Math.min(runs.length, 3) - 16));
  // The maps share the window with the plots below: their height is bounded too.
  const maxH = Math.max(260, window.innerHeight - 440);
  const scale = Math.min(avail / (hi[0] - lo[0]), maxH / (hi[1] - lo[1]));
  const mapW = Math.round((hi[0] - lo[0]) * scale), mapH = Math.round((hi[1] - lo[1]) * scale);
  const X = (x) => (x - lo[0]) * scale, Y = (y) => mapH - (y - lo[1]) * scale;

  // Panels.
  const panels = document.getElementById("panels");
  for (let k = 0; k < runs.length; k++) {
    const r = runs[k];
    const div = document.createElement("div");
    div.className = "panel";
    const h = document.createElement("h2");
    h.textContent = r.name;
    h.style.color = runColors[k % runColors.length];
    const c = document.createElement("canvas");
    c.width = mapW; c.height = mapH;
    c.className = "map";
    const counts = document.createElement("div");
    counts.className = "counts";
    div.append(h, c, counts);
    div.style.width = Math.max(mapW, 240) + "px";  // the counts wrap under the map
    panels.append(div);
    r.canvas = c; r.ctx = c.getContext("2d"); r.countsDiv = counts;
    r.color = runColors[k % runColors.length];
    // Static layer: the floor plan.
    const layer = document.createElement("canvas");
    layer.width = mapW; layer.height = mapH;
    const g = layer.getContext("2d");
    g.fillStyle = "#fff"; g.fillRect(0, 0, mapW, mapH);
    const poly = (pts, fill, stroke, width) => {
      if (pts.length < 4) return;
      g.beginPath(); g.moveTo(X(pts[0]), Y(pts[1]));
      for (let i = 2; i + 1 < pts.length; i += 2) g.lineTo(X(pts[i]), Y(pts[i + 1]));
      if (fill) { g.closePath(); g.fillStyle = fill; g.fill(); }
      if (stroke) { g.strokeStyle = stroke; g.lineWidth = width; g.stroke(); }
    };
    for (const p of D.plan.blocks) poly(p, "#e3e3e3", "#b0b0b0", 1);
    for (const p of D.plan.boxes) poly(p, "#ede3d2", "#b0b0b0", 1);
    for (const p of D.plan.walls) poly(p, null, "#404040", 2.5);
    r.layer = layer;
  }

  // Sample of run r at the global frame `frame`: the last sample at or before it.
  function sampleAt(r, frame) {
    const f = r.frames.f;
    let a = 0, b = f.length - 1;
    if (frame < f[0]) return -1;
    while (a < b) { const m = (a + b + 1) >> 1; if (f[m] <= frame) a = m; else b = m - 1; }
    return a;
  }
  // Number of entries of the sorted array `arr` that are <= v.
  function countLe(arr, v) {
    let a = 0, b = arr.length;
    while (a < b) { const m = (a + b) >> 1; if (arr[m] <= v) a = m + 1; else b = m; }
    return a;
  }

  function path(ctx, xs, ys, upto, color, width, alpha) {
    ctx.save(); ctx.globalAlpha = alpha; ctx.strokeStyle = color; ctx.lineWidth = width;
    ctx.beginPath();
    let open = false;
    for (let i = 0; i <= upto; i++) {
      if (xs[i] === null || ys[i] === null) { open = false; continue; }
      if (!open) { ctx.moveTo(X(xs[i]), Y(ys[i])); open = true; } else ctx.lineTo(X(xs[i]), Y(ys[i]));
    }
    ctx.stroke(); ctx.restore();
  }
  function pose(ctx, x, y, phi, color) {
    const px = X(x), py = Y(y), L = 9;
    ctx.save(); ctx.translate(px, py); ctx.rotate(-phi);
    ctx.beginPath(); ctx.moveTo(L, 0); ctx.lineTo(-L * 0.6, L * 0.5); ctx.lineTo(-L * 0.6, -L * 0.5);
    ctx.closePath(); ctx.fillStyle = color; ctx.fill(); ctx.restore();
  }

  const state = { index: 0, frame: base.f[0], session: base.s[0], redraws: 0, runs: [] };
  window.replayState = state;

  function drawRun(r, frame) {
    const ctx = r.ctx, f = r.frames, V = r.views, W = r.weak;
    ctx.drawImage(r.layer, 0, 0);
    const i = sampleAt(r, frame);
    const weakN = countLe(W.f, frame);
    const lost = new Uint16Array(V.x.length);
    const ringed = new Uint8Array(V.x.length);
    for (let k = 0; k < weakN; k++) {
      const v = W.v[k];
      if (lost[v] < 65535) lost[v]++;
      if (frame - W.f[k] < flashFrames) ringed[v] = 1;
    }
    let alive = 0, weakened = 0, removedRecent = 0, removedTotal = 0;
    // One path per style (new or not x four shades by components lost; rings; crosses):
    // a few fill/stroke calls per redraw however many views there are.
    const dots = [new Path2D(), new Path2D(), new Path2D(), new Path2D(), new Path2D(),
                  new Path2D(), new Path2D(), new Path2D()];
    const rings = new Path2D(), crossActive = new Path2D(), crossOther = new Path2D();
    const addCross = (p, x, y) => {
      const px = X(x), py = Y(y);
      p.moveTo(px - 4, py - 4); p.lineTo(px + 4, py + 4);
      p.moveTo(px - 4, py + 4); p.lineTo(px + 4, py - 4);
    };
    for (let v = 0; v < V.x.length; v++) {
      const born = V.born[v], died = V.died[v];
      if (born > frame) continue;
      if (died >= 0 && died <= frame) {
        removedTotal++;
        if (frame - died < flashFrames) {
          removedRecent++;
          addCross(V.why[v] === 1 ? crossActive : crossOther, V.x[v], V.y[v]);
        }
        continue;
      }
      alive++;
      const px = X(V.x[v]), py = Y(V.y[v]);
      const p = dots[(frame - born < flashFrames ? 4 : 0) + Math.min(3, lost[v])];
      p.moveTo(px + 2.6, py); p.arc(px, py, 2.6, 0, 2 * Math.PI);
      if (ringed[v]) {
        weakened++;
        rings.moveTo(px + 5.5, py); rings.arc(px, py, 5.5, 0, 2 * Math.PI);
      }
    }
    for (let k = 0; k < 8; k++) {
      ctx.globalAlpha = 1 - 0.25 * (k % 4);
      ctx.fillStyle = k < 4 ? "#2166ac" : "#1a9850";
      ctx.fill(dots[k]);
    }
    ctx.globalAlpha = 1;
    ctx.strokeStyle = "#f28e2b"; ctx.lineWidth = 1.5; ctx.stroke(rings);
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#c0102a"; ctx.stroke(crossActive);
    ctx.strokeStyle = "#7b3294"; ctx.stroke(crossOther);
    let estimate = false;
    if (i >= 0) {
      path(ctx, f.tx, f.ty, i, "#222", 1, 0.45);
      path(ctx, f.ex, f.ey, i, r.color, 1.3, 0.8);
      if (f.tx[i] !== null) pose(ctx, f.tx[i], f.ty[i], f.tp[i], "#222");
      if (f.ex[i] !== null) {
        estimate = true;
        pose(ctx, f.ex[i], f.ey[i], f.ep[i], r.color);
        const cxx = f.cxx[i], cxy = f.cxy[i], cyy = f.cyy[i];
        if (cxx !== null && cxy !== null && cyy !== null) {
          const m = (cxx + cyy) / 2, d = Math.sqrt(((cxx - cyy) / 2) ** 2 + cxy ** 2);
          const l1 = Math.max(m + d, 0), l2 = Math.max(m - d, 0);
          const ang = 0.5 * Math.atan2(2 * cxy, cxx - cyy);
          ctx.strokeStyle = r.color; ctx.lineWidth = 1.5;
          ctx.beginPath();
          ctx.ellipse(X(f.ex[i]), Y(f.ey[i]), Math.max(2 * Math.sqrt(l1) * scale, 0.5),
                      Math.max(2 * Math.sqrt(l2) * scale, 0.5), -ang, 0, 2 * Math.PI);
          ctx.stroke();
        }
      }
    }
    const err = i >= 0 ? f.e[i] : null;
    r.countsDiv.textContent = alive + " views (map size " + (i >= 0 ? f.v[i] : 0) + "), " +
      removedTotal + " removed so far, " + weakN + (W.total > W.f.length ? " (sampled)" : "") +
      " components lost; error " + (err === null ? "-" : err.toFixed(2) + " m") +
      (estimate ? "" : " (no estimate)");
    return { name: r.name, views: alive, weakened: weakened, removed_recent: removedRecent,
             removed_total: removedTotal, estimate: estimate };
  }

  // Plots below: map size and error over the run, day boundaries, a cursor.
  const chart = document.getElementById("chart");
  chart.width = Math.max(600, Math.min(1800, window.innerWidth - 60));
  chart.height = 330;
  const cctx = chart.getContext("2d");
  const chartLayer = document.createElement("canvas");
  chartLayer.width = chart.width; chartLayer.height = chart.height;
  const L = 60, R = 150, plotW = chart.width - L - R;
  const f0 = base.f[0], f1 = Math.max(base.f[nSamples - 1], f0 + 1);
  const CX = (fr) => L + (fr - f0) / (f1 - f0) * plotW;
  const boxes = [{ top: 22, h: 120, key: "v", label: "reference views" },
                 { top: 178, h: 120, key: "e", label: "position error [m]" }];
  (function drawChart() {
    const g = chartLayer.getContext("2d");
    g.fillStyle = "#fff"; g.fillRect(0, 0, chart.width, chart.height);
    g.font = "11px sans-serif";
    for (const b of boxes) {
      let ymax = 0;
      for (const r of runs) for (const v of r.frames[b.key]) if (v !== null && v > ymax) ymax = v;
      if (b.key === "e") for (const v of base.o) if (v !== null && v > ymax) ymax = v;
      if (b.key === "e") {  // errors: up to the 99th percentile, so one outlier does not flatten all
        const all = [];
        for (const r of runs) for (const v of r.frames.e) if (v !== null) all.push(v);
        all.sort((a, c) => a - c);
        if (all.length) ymax = Math.max(all[Math.floor(0.99 * (all.length - 1))] * 1.1, 1e-3);
      }
      if (ymax <= 0) ymax = 1;
      b.ymax = ymax;
      const CY = (v) => b.top + b.h - Math.min(v, ymax) / ymax * b.h;
      g.strokeStyle = "#000"; g.lineWidth = 1; g.strokeRect(L, b.top, plotW, b.h);
      g.fillStyle = "#000"; g.textAlign = "right";
      for (const t of [0, 0.5, 1]) g.fillText((ymax * t).toPrecision(3), L - 4, CY(ymax * t) + 4);
      g.save(); g.translate(14, b.top + b.h / 2); g.rotate(-Math.PI / 2); g.textAlign = "center";
      g.fillText(b.label, 0, 0); g.restore();
      // Day boundaries.
      g.setLineDash([4, 3]); g.strokeStyle = "#888";
      g.textAlign = "left"; g.fillStyle = "#666";
      for (const [fr, s] of D.days) {
        g.beginPath(); g.moveTo(CX(fr), b.top); g.lineTo(CX(fr), b.top + b.h); g.stroke();
        g.fillText("day " + (s + 1), CX(fr) + 3, b.top + 10);
      }
      g.setLineDash([]);
      const series = runs.map((r) => ({ name: r.name, ys: r.frames[b.key], xs: r.frames.f, color: r.color }));
      if (b.key === "e") series.push({ name: "odometry only", ys: base.o, xs: base.f, color: "#999" });
      series.forEach((s, k) => {
        g.strokeStyle = s.color; g.lineWidth = 1.2; g.beginPath();
        let open = false;
        for (let i = 0; i < s.xs.length; i++) {
          const y = s.ys[i];
          if (y === null) { open = false; continue; }
          if (!open) { g.moveTo(CX(s.xs[i]), CY(y)); open = true; } else g.lineTo(CX(s.xs[i]), CY(y));
        }
        g.stroke();
        g.fillStyle = s.color; g.fillRect(L + plotW + 10, b.top + 6 + 14 * k, 10, 10);
        g.fillStyle = "#000"; g.fillText(s.name, L + plotW + 24, b.top + 15 + 14 * k);
      });
    }
    g.textAlign = "center"; g.fillStyle = "#000";
    g.fillText("frame", L + plotW / 2, chart.height - 6);
    for (const t of [f0, Math.round((f0 + f1) / 2), f1]) g.fillText(String(t), CX(t), 312);
  })();

  function drawCursor(frame) {
    cctx.drawImage(chartLayer, 0, 0);
    cctx.strokeStyle = "#d62728"; cctx.lineWidth = 1.5;
    cctx.beginPath(); cctx.moveTo(CX(frame), 18); cctx.lineTo(CX(frame), 300); cctx.stroke();
  }

  function update() {
    const index = Math.max(0, Math.min(nSamples - 1, Number(slider.value) | 0));
    const frame = base.f[index];
    state.index = index; state.frame = frame; state.session = base.s[index];
    state.runs = runs.map((r) => drawRun(r, frame));
    drawCursor(frame);
    state.redraws++;
    document.getElementById("label").textContent =
      "frame " + frame + " of " + base.f[nSamples - 1] + ", day " + (base.s[index] + 1);
  }
  slider.addEventListener("input", update);
  function seek(ev) {
    const rect = chart.getBoundingClientRect();
    const fr = f0 + (ev.clientX - rect.left - L) / plotW * (f1 - f0);
    let a = 0, b = nSamples - 1;
    while (a < b) { const m = (a + b) >> 1; if (base.f[m] < fr) a = m + 1; else b = m; }
    slider.value = a;
    update();
  }
  let dragging = false;
  chart.addEventListener("mousedown", (ev) => { dragging = true; seek(ev); });
  window.addEventListener("mouseup", () => { dragging = false; });
  chart.addEventListener("mousemove", (ev) => { if (dragging) seek(ev); });
  let timer = null;
  const play = document.getElementById("play");
  play.addEventListener("click", () => {
    if (timer !== null) { clearInterval(timer); timer = null; play.textContent = "play"; return; }
    play.textContent = "pause";
    const step = Math.max(1, Math.round(nSamples / 600));
    timer = setInterval(() => {
      if (Number(slider.value) >= nSamples - 1) { clearInterval(timer); timer = null; play.textContent = "play"; return; }
      slider.value = Math.min(nSamples - 1, Number(slider.value) + step);
      update();
    }, 30);
  });
  update();
})();
)JS";

}  // namespace

void ReplayOptions::Validate() const {
  if (max_samples < 2) throw Error(StrCat("max_samples must be >= 2 (got ", max_samples, ")"));
  if (max_weakening_events < 0)
    throw Error(StrCat("max_weakening_events must be >= 0 (got ", max_weakening_events, ")"));
}

std::vector<MapEvent> ReadEventsCsv(const fs::path& path) {
  std::vector<MapEvent> events;
  std::error_code ec;
  if (!fs::exists(path, ec)) return events;
  LineReader in(path, "events");
  std::string line;
  if (!in.Next(&line)) return events;
  const std::vector<std::string> header = SplitQuotedCsv(line);
  const std::vector<std::string> expected = {"type", "frame", "session", "view_id", "component_id",
                                             "x_m",  "y_m",   "phi_rad", "weight",  "reason"};
  if (header != expected)
    throw Error(StrCat(path.string(), ":1: not an events.csv header (expected ",
                       "type,frame,session,view_id,component_id,x_m,y_m,phi_rad,weight,reason)"));
  while (in.Next(&line)) {
    if (line.empty()) continue;
    const std::string where = StrCat(path.string(), ":", in.line_number());
    const std::vector<std::string> c = SplitQuotedCsv(line);
    if (c.size() != expected.size())
      throw Error(StrCat(where, ": ", c.size(), " cells, expected ", expected.size()));
    MapEvent e;
    e.type = EventTypeFromString(c[0], where);
    e.frame = ParseInt(c[1], where, "frame");
    e.session = static_cast<int>(ParseInt(c[2], where, "session"));
    e.view_id = static_cast<std::uint64_t>(ParseInt(c[3], where, "view_id"));
    e.component_id = static_cast<std::uint64_t>(ParseInt(c[4], where, "component_id"));
    e.position = Pose2(ParseDouble(c[5], where, "x_m"), ParseDouble(c[6], where, "y_m"),
                       ParseDouble(c[7], where, "phi_rad"));
    e.weight = ParseDouble(c[8], where, "weight");
    e.reason = c[9];
    events.push_back(std::move(e));
  }
  return events;
}

std::string RenderReplayHtml(const std::vector<ReplayRun>& runs, const ReplayOptions& options) {
  options.Validate();
  if (runs.empty() || runs.front().records.empty()) throw Error("replay: no frames to show");
  json data;
  data["title"] = options.title;
  data["input"] = options.input;
  data["plan"] = PlanJson(options.floor_plan);
  data["frames_total"] = runs.front().records.size();
  data["sample_limit"] = options.max_samples;
  json days = json::array();
  for (const auto& [frame, session] : DayStarts(runs.front().records))
    days.push_back({frame, session});
  data["days"] = days;
  json runs_json = json::array();
  for (const ReplayRun& run : runs) {
    if (run.records.empty()) continue;
    json r = ViewsJson(run.events, options.max_weakening_events);
    r["name"] = run.name;
    r["frames"] = FramesJson(run.records, SampleIndices(run.records, options.max_samples));
    runs_json.push_back(std::move(r));
  }
  data["runs"] = runs_json;
  std::ostringstream os;
  os << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>"
     << XmlEscape(options.title) << "</title>\n<style>" << kStyle << "</style>\n</head>\n<body>\n"
     << "<h1 id=\"title\"></h1>\n<div id=\"input\"></div>\n"
     << "<div id=\"controls\"><button id=\"play\" type=\"button\">play</button>"
     << "<input id=\"slider\" type=\"range\" step=\"1\" aria-label=\"frame\">"
     << "<span id=\"label\"></span></div>\n"
     << "<div id=\"legend\"><span>&#9679; <b style=\"color:#2166ac\">view</b> (paler: "
        "components lost)</span><span style=\"color:#1a9850\">&#9679; new view</span>"
        "<span style=\"color:#f28e2b\">&#9711; component just removed (weakened)</span>"
        "<span style=\"color:#c0102a\">&#10005; view removed by active forgetting</span>"
        "<span style=\"color:#7b3294\">&#10005; view removed otherwise (passive, merge)</span>"
        "<span>&#9650; black: ground truth; coloured: estimate with its 2-sigma ellipse</span>"
        "</div>\n"
     << "<div id=\"panels\"></div>\n<canvas id=\"chart\"></canvas>\n<p id=\"note\"></p>\n"
     << "<script type=\"application/json\" id=\"replay-data\">" << ScriptSafeJson(data)
     << "</script>\n<script>" << kScript << "</script>\n</body>\n</html>\n";
  return os.str();
}

namespace {

// The "# input: ..." line of RUNDIR/config.yaml ("" when absent).
std::string ReadInputLine(const fs::path& run_dir) {
  const fs::path config = run_dir / "config.yaml";
  std::error_code ec;
  if (!fs::is_regular_file(config, ec)) return "";
  LineReader in(config, "config");
  std::string line;
  const std::string prefix = "# input: ";
  while (in.Next(&line)) {
    if (line.rfind(prefix, 0) == 0) return line.substr(prefix.size());
    if (!line.empty() && line[0] != '#') break;
  }
  return "";
}

ReplayRun ReadRun(const fs::path& run_dir, std::string name) {
  ReplayRun run;
  run.name = std::move(name);
  run.records = ReadFramesCsv(run_dir / "frames.csv").records;
  run.events = ReadEventsCsv(run_dir / "events.csv");
  return run;
}

}  // namespace

fs::path WriteReplay(const fs::path& dir, ReplayOptions options) {
  std::vector<ReplayRun> runs;
  fs::path config_dir;
  std::error_code ec;
  if (fs::is_regular_file(dir / "frames.csv", ec)) {
    runs.push_back(ReadRun(dir, ""));
    config_dir = dir;
  } else {
    for (const char* mode : {"passive", "active", "static"}) {
      if (fs::is_regular_file(dir / mode / "frames.csv", ec)) {
        runs.push_back(ReadRun(dir / mode, mode));
        if (config_dir.empty()) config_dir = dir / mode;
      }
    }
  }
  if (runs.empty())
    throw Error(StrCat("'", dir.string(),
                       "' is neither a run directory (frames.csv) nor a compare directory"));
  if (options.input.empty()) options.input = ReadInputLine(config_dir);
  if (runs.size() == 1 && runs.front().name.empty()) {
    const std::string mode = ReadRunForgetting(config_dir);
    runs.front().name = mode.empty() ? "run" : "run (" + mode + " forgetting)";
  }
  if (options.title == ReplayOptions{}.title)
    options.title = StrCat("omnicml replay: ", fs::absolute(dir).lexically_normal().string());
  if (options.floor_plan.empty() && !options.input.empty())
    options.floor_plan = FloorPlanForRunInput(options.input);
  const fs::path out = dir / "replay.html";
  WriteFileAtomic(out, RenderReplayHtml(runs, options));
  return out;
}

}  // namespace omnicml
