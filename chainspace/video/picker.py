"""A standalone HTML page to place a chain's points on video frames by clicking: ``chainspace pick``.

The page embeds the frames (base64 JPEG), lists the points in order with the current one highlighted,
and places it where the user clicks (undo, skip, zoom); the key-frame JSON
(:mod:`chainspace.video.keyframes`) it shows updates with every click and can be copied or
downloaded. Coordinates are image pixels (x right, y down, the top-left pixel's centre at (0, 0))
whatever the page's zoom or the browser's scaling.
"""

from __future__ import annotations

import base64
import html
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import VideoError
from .reader import Video, open_video

__all__ = ["write_picker"]

_PAGE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>chainspace: pick points on __TITLE__</title>
<style>
body { font-family: system-ui, sans-serif; margin: 0; display: flex; height: 100vh; }
#side { width: 260px; padding: 10px; overflow-y: auto; border-right: 1px solid #ccc; box-sizing: border-box; flex: none; }
#main { flex: 1; overflow: auto; padding: 10px; }
#stage { position: relative; display: inline-block; line-height: 0; cursor: crosshair; }
#stage img { display: block; width: 100%; height: auto; user-select: none; -webkit-user-drag: none; }
#marks { position: absolute; left: 0; top: 0; width: 100%; height: 100%; pointer-events: none; overflow: visible; }
ol { padding-left: 24px; } li { padding: 2px 4px; border-radius: 3px; }
li.current { background: #ffd54f; font-weight: bold; } li.done { color: #2e7d32; } li.skipped { color: #999; }
textarea { width: 100%; height: 160px; font-family: monospace; font-size: 11px; box-sizing: border-box; }
button, select { margin: 2px 2px 2px 0; }
.help { color: #555; font-size: 12px; }
</style></head>
<body>
<div id="side">
 <div><b>__TITLE__</b></div>
 <div class="help">Click each point in turn, in the order listed. Pixels: x right, y down.</div>
 <div>Frame: <select id="frame"></select></div>
 <div>Zoom: <select id="zoom"><option value="fit">fit</option><option value="1">100%</option>
  <option value="2">200%</option><option value="4">400%</option></select></div>
 <div><button id="undo" title="Ctrl+Z">Undo</button><button id="skip" title="not visible in this frame">Skip</button></div>
 <ol id="names"></ol>
 <div><button id="copy">Copy JSON</button><button id="download">Download JSON</button></div>
 <textarea id="json" readonly></textarea>
 <div class="help">Give the file to <code>chainspace track VIDEO --points FILE.json</code>.</div>
</div>
<div id="main"><div id="stage"><img id="image" alt="video frame" draggable="false">
 <svg id="marks" xmlns="http://www.w3.org/2000/svg"></svg></div></div>
<script>
"use strict";
const DATA = __DATA__;
const names = DATA.names;
const fixedNames = DATA.fixed_names;
const state = {};          // frame -> {name: [x, y]} in the order clicked
const history = {};        // frame -> list of names placed or skipped (for undo)
let current = DATA.frames[0].index;
const img = document.getElementById("image"), stage = document.getElementById("stage");
const marks = document.getElementById("marks");
for (const f of DATA.frames) {
  state[f.index] = {}; history[f.index] = [];
  const o = document.createElement("option"); o.value = f.index; o.textContent = f.index;
  document.getElementById("frame").appendChild(o);
}
function frameData() { return DATA.frames.find(f => f.index === current); }
function nameList() {
  if (fixedNames) return names;
  const n = history[current].length;
  return Array.from({length: n + 1}, (_, i) => "point_" + (i + 1));
}
function nextName() { return nameList()[history[current].length]; }
function keyframes() {
  const out = {};
  for (const f of DATA.frames) {
    const pts = {};
    for (const n of history[f.index]) if (state[f.index][n] !== undefined) pts[n] = state[f.index][n];
    if (Object.keys(pts).length) out[String(f.index)] = pts;
  }
  return out;
}
function render() {
  const list = document.getElementById("names"); list.innerHTML = "";
  const done = history[current];
  nameList().forEach((n, i) => {
    const li = document.createElement("li"); li.textContent = n;
    if (i < done.length) li.className = state[current][n] ? "done" : "skipped";
    else if (i === done.length) li.className = "current";
    list.appendChild(li);
  });
  const f = frameData();
  marks.setAttribute("viewBox", `-0.5 -0.5 ${f.width} ${f.height}`);
  const r = Math.max(f.width, f.height) / 200;
  marks.innerHTML = done.filter(n => state[current][n]).map(n => {
    const [x, y] = state[current][n];
    return `<circle cx="${x}" cy="${y}" r="${r}" fill="none" stroke="#ff1744" stroke-width="${r / 2}"/>` +
      `<text x="${x + 1.5 * r}" y="${y - 1.5 * r}" fill="#ff1744" font-size="${4 * r}">${n}</text>`;
  }).join("");
  document.getElementById("json").value = JSON.stringify(keyframes(), null, 1);
  document.getElementById("skip").disabled = !fixedNames || nextName() === undefined;
}
function showFrame(index) {
  current = index;
  const f = frameData();
  img.src = "data:image/jpeg;base64," + f.jpeg;
  applyZoom(); render();
}
function applyZoom() {
  const z = document.getElementById("zoom").value, f = frameData();
  stage.style.width = z === "fit" ? "100%" : (f.width * Number(z)) + "px";
}
stage.addEventListener("click", ev => {
  const name = nextName();
  if (name === undefined) return;
  const rect = img.getBoundingClientRect(), f = frameData();
  // CSS pixels -> image pixels; -0.5 because the top-left pixel's centre is (0, 0)
  const x = (ev.clientX - rect.left) * f.width / rect.width - 0.5;
  const y = (ev.clientY - rect.top) * f.height / rect.height - 0.5;
  state[current][name] = [Math.round(x * 100) / 100, Math.round(y * 100) / 100];
  history[current].push(name); render();
});
function undo() {
  const n = history[current].pop();
  if (n !== undefined) delete state[current][n];
  render();
}
document.getElementById("undo").onclick = undo;
document.getElementById("skip").onclick = () => { const n = nextName(); if (n !== undefined) { history[current].push(n); render(); } };
document.addEventListener("keydown", ev => { if ((ev.ctrlKey || ev.metaKey) && ev.key === "z") { undo(); ev.preventDefault(); } });
document.getElementById("frame").onchange = ev => showFrame(Number(ev.target.value));
document.getElementById("zoom").onchange = () => applyZoom();
document.getElementById("copy").onclick = () => {
  const t = document.getElementById("json"); t.select();
  if (navigator.clipboard) navigator.clipboard.writeText(t.value).catch(() => document.execCommand("copy"));
  else document.execCommand("copy");
};
document.getElementById("download").onclick = () => {
  const blob = new Blob([document.getElementById("json").value + "\n"], {type: "application/json"});
  const a = document.createElement("a"); a.href = URL.createObjectURL(blob); a.download = DATA.download;
  document.body.appendChild(a); a.click(); a.remove();
};
window.chainspaceKeyframes = keyframes;  // for scripts and tests
showFrame(current);
</script></body></html>
"""


def write_picker(video: Video | str | os.PathLike, out: str | os.PathLike, frames: Sequence[int] = (0,), *,
                 chain: Any = None, names: Sequence[str] | None = None, fps: float | None = None,
                 quality: int = 90, overwrite: bool = False) -> Path:
    """Write the point-picking page for ``frames`` of ``video`` to ``out`` (HTML, standalone).

    Parameters
    ----------
    video
        A :class:`~chainspace.video.reader.Video` or the path of a video file or image folder.
    out
        The HTML file; not replaced unless ``overwrite``.
    frames
        Frame indices (0-based) to show; the page switches between them.
    chain, names
        The points to click, in order: a :class:`chainspace.KinematicChain` (or its name/file) gives
        its joints; ``names`` a list. With neither, the points are named ``point_1``, ``point_2``, ...
    fps
        Frame rate of an image folder (not used otherwise; a folder needs one to open).
    quality
        JPEG quality of the embedded frames, 1 to 100.
    """
    import cv2

    from ..io.results import atomic_write, check_writable

    if chain is not None and names is not None:
        raise VideoError("give the points as chain= or as names=, not both")
    if chain is not None:
        from .tracking import _chain_names

        names = _chain_names(chain)
    if names is not None:
        names = [str(n) for n in names]
        if not names or len(set(names)) != len(names):
            raise VideoError(f"the point names must be distinct and at least one: {names}")
    frames = sorted({int(f) for f in frames})
    if not frames:
        raise VideoError("give at least one frame to pick points on")
    if not (isinstance(quality, int) and 1 <= quality <= 100):
        raise VideoError(f"quality must be an integer from 1 to 100, not {quality!r}")
    check_writable([out], overwrite)
    own = not isinstance(video, Video)
    vid = open_video(video, 1.0 if fps is None and Path(video).is_dir() else fps) if own else video
    try:
        shown = []
        for index in frames:
            image = vid.frame(index)
            ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                raise VideoError(f"{vid.path}: frame {index} could not be encoded as JPEG")
            shown.append({"index": index, "width": vid.size[0], "height": vid.size[1],
                          "jpeg": base64.b64encode(jpeg.tobytes()).decode("ascii")})
    finally:
        if own:
            vid.close()
    data = {"names": names or [], "fixed_names": names is not None, "frames": shown,
            "download": f"{Path(vid.path).stem}_keyframes.json"}
    # "</" inside the JSON cannot close the script element
    page = (_PAGE.replace("__TITLE__", html.escape(Path(vid.path).name))
            .replace("__DATA__", json.dumps(data).replace("</", "<\\/")))
    with atomic_write(out, "w", overwrite) as f:
        f.write(page)
    return Path(out)
