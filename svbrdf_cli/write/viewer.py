"""``svbrdf view SET``: a self-contained ``viewer.html`` beside a texture set (native, or a preset's).

The page shows the material on a plane under a point light that follows the mouse, rendered by a
small hand-written WebGL shader with our conventions: the same Cook-Torrance (GGX, Smith-Schlick
with k = a/2, Schlick Fresnel, ``d (1 - s) / pi`` diffuse), the same geometry (the surface spans
[-1, 1]², the camera at :data:`svbrdf_cli.conventions.FLASH_POSITION`) and the same 2.2 encodings
as :mod:`svbrdf_cli.shading`. The maps are embedded as data URIs (a browser will not hand a page
opened from disk the pixels of sibling files), and nothing is fetched from the network. Toggles
replace a map by a neutral one (flat normal, grey diffuse, roughness 0.5, F0 0.04); tiling repeats
the maps 1-3 times; sliders set the light's intensity and height. The page has a title and says how
to move the light; the canvas is the largest square the window leaves, redrawn when the window
changes, at the screen's resolution up to ``size`` pixels. Without WebGL the page says so instead
of showing a blank canvas. ``?light=x,y,z&intensity=I`` in the URL fixes the light, ``?bare``
shows the canvas alone (for embedding; what the tests use).
"""

from __future__ import annotations

import base64
import html
import json
import os

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.write import ownership
from svbrdf_cli.write.atomic import write_text
from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.write.mapset import linear_to_stored
from svbrdf_cli.write.readback import is_native, read_any_set

#: The viewer's file name in the set's folder.
VIEWER = "viewer.html"

_FRAGMENT = """
precision highp float;
uniform sampler2D uN, uD, uR, uS;
uniform vec3 uLight, uCam;
uniform float uI, uTile;
uniform vec4 uUse;
varying vec2 vUv;
const float PI = 3.141592653589793;
const float EPS = %(eps)s;
void main() {
  vec2 uv = fract(vUv * uTile);
  vec3 n = uUse.x > 0.5 ? normalize(texture2D(uN, uv).rgb * 2.0 - 1.0) : vec3(0.0, 0.0, 1.0);
  vec3 d = uUse.y > 0.5 ? pow(texture2D(uD, uv).rgb, vec3(%(albedo_gamma)s)) : vec3(0.5);
  float r = uUse.z > 0.5 ? texture2D(uR, uv).r : 0.5;
  vec3 s = uUse.w > 0.5 ? pow(texture2D(uS, uv).rgb, vec3(%(albedo_gamma)s)) : vec3(%(f0)s);
  vec3 p = vec3((vUv.x * 2.0 - 1.0) * %(half)s, (1.0 - vUv.y * 2.0) * %(half)s, 0.0);
  vec3 toL = uLight - p;
  float d2 = dot(toL, toL);
  vec3 l = toL / sqrt(d2);
  vec3 v = normalize(uCam - p);
  vec3 h = normalize(l + v);
  float a = r * r, a2 = a * a;
  float nh = clamp(dot(n, h), 0.0, 1.0);
  float q = max(nh * nh * (a2 - 1.0) + 1.0, EPS);
  float D = a2 / (PI * q * q);
  float k = a * 0.5;
  float nl = clamp(dot(n, l), 0.0, 1.0), nv = clamp(dot(n, v), 0.0, 1.0);
  float V = 1.0 / (max(nl * (1.0 - k) + k, EPS) * max(nv * (1.0 - k) + k, EPS));
  vec3 F = s + (1.0 - s) * pow(1.0 - clamp(dot(v, h), 0.0, 1.0), 5.0);
  vec3 f = d * (1.0 - s) / PI + D * F * V * 0.25;
  vec3 rad = uI * PI * f * max(dot(n, l), 0.0) * (l.z > 0.0 ? 1.0 : 0.0) / d2;
  gl_FragColor = vec4(pow(clamp(rad, 0.0, 1.0), vec3(1.0 / %(image_gamma)s)), 1.0);
}
"""

_PAGE = """<!doctype html>
<html><head><meta charset="utf-8">%(generator)s<meta name="viewport" content="width=device-width, initial-scale=1">
<title>svbrdf viewer: %(name)s</title>
<style>
html, body { height: 100%%; }
body { margin: 0; background: #1e1e1e; color: #ddd; font-family: system-ui, sans-serif; display: flex;
       flex-direction: column; }
header { padding: 8px 12px; background: #262626; font-size: 13px; }
h1 { font-size: 16px; margin: 0 12px 0 0; display: inline; } .hint { color: #aaa; }
#ui { margin-top: 6px; } label { margin-right: 12px; white-space: nowrap; }
main { flex: 1; min-height: 0; display: flex; align-items: center; justify-content: center; }
#c { display: block; cursor: crosshair; }
#nogl { display: none; max-width: 36em; padding: 2em; line-height: 1.5; }
body.bare header { display: none; }
</style></head><body>
<header><h1>%(name)s</h1><span class="hint">Move the mouse over the material to move the light.</span>
<div id="ui">
<label><input type="checkbox" id="useN" checked> normal</label>
<label><input type="checkbox" id="useD" checked> diffuse</label>
<label><input type="checkbox" id="useR" checked> roughness</label>
<label><input type="checkbox" id="useS" checked> specular</label>
<label>tiling <select id="tile"><option>1</option><option>2</option><option>3</option></select></label>
<label>light <input type="range" id="inten" min="-3" max="3" step="0.1" value="0"> stops</label>
<label>light height <input type="range" id="lz" min="0.3" max="4" step="0.05" value="%(cam_z)s"></label>
</div></header>
<main><canvas id="c" width="%(size)d" height="%(size)d"></canvas>
<div id="nogl"><b>This page needs WebGL to draw the material, and this browser has none</b> (it is turned
off, or the graphics driver is blocked). Turn on hardware acceleration, or try another browser. The maps
themselves are the PNG files beside this page.</div>
<noscript><div style="padding: 2em">This page needs JavaScript (and WebGL) to draw the material.</div></noscript></main>
<script>
"use strict";
var MAPS = %(maps)s;
var CAM = %(cam)s, INTENSITY = %(intensity)s, HALF = %(half)s, MAX_SIDE = %(size)d;
var params = new URLSearchParams(location.search);
if (params.has("bare")) document.body.className = "bare";  // the canvas alone (embedding; the tests)
var light = CAM.slice();
if (params.get("light")) light = params.get("light").split(",").map(Number);
var scale = params.get("intensity") ? Number(params.get("intensity")) / INTENSITY : 1.0;
var canvas = document.getElementById("c");
var gl = null;
try { gl = canvas.getContext("webgl", {preserveDrawingBuffer: true}); } catch (e) { gl = null; }
function val(id) { return document.getElementById(id); }
function fit() {
  // the largest square the window leaves below the header; drawn at the screen's resolution (at most MAX_SIDE)
  var main = document.querySelector("main");
  var side = Math.max(64, Math.floor(Math.min(main.clientWidth, main.clientHeight)));
  canvas.style.width = side + "px"; canvas.style.height = side + "px";
  var px = Math.min(MAX_SIDE, Math.round(side * (window.devicePixelRatio || 1)));
  if (canvas.width !== px) { canvas.width = px; canvas.height = px; }
}
if (!gl) {
  canvas.style.display = "none"; val("ui").style.display = "none"; val("nogl").style.display = "block";
  document.title = "svbrdf viewer: no WebGL";
} else {
function shader(type, src) {
  var s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
var prog = gl.createProgram();
gl.attachShader(prog, shader(gl.VERTEX_SHADER,
  "attribute vec2 aPos; varying vec2 vUv; void main() { vUv = vec2(aPos.x * 0.5 + 0.5, 0.5 - aPos.y * 0.5);" +
  " gl_Position = vec4(aPos, 0.0, 1.0); }"));
gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, %(fragment)s));
gl.linkProgram(prog); gl.useProgram(prog);
var buf = gl.createBuffer(); gl.bindBuffer(gl.ARRAY_BUFFER, buf);
gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
var loc = gl.getAttribLocation(prog, "aPos"); gl.enableVertexAttribArray(loc);
gl.vertexAttribPointer(loc, 2, gl.FLOAT, false, 0, 0);
var names = ["uN", "uD", "uR", "uS"], keys = ["normal", "diffuse", "roughness", "specular"], pending = 4;
keys.forEach(function (k, i) {
  var img = new Image();
  img.onload = function () {
    var t = gl.createTexture(); gl.activeTexture(gl.TEXTURE0 + i); gl.bindTexture(gl.TEXTURE_2D, t);
    gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, img);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.uniform1i(gl.getUniformLocation(prog, names[i]), i);
    if (--pending === 0) draw();
  };
  img.src = MAPS[k];
});
var draw = function () {
  if (pending > 0) return;
  fit();
  gl.uniform3fv(gl.getUniformLocation(prog, "uLight"), light);
  gl.uniform3fv(gl.getUniformLocation(prog, "uCam"), CAM);
  gl.uniform1f(gl.getUniformLocation(prog, "uI"), INTENSITY * scale * Math.pow(2, Number(val("inten").value)));
  gl.uniform1f(gl.getUniformLocation(prog, "uTile"), Number(val("tile").value));
  gl.uniform4f(gl.getUniformLocation(prog, "uUse"), val("useN").checked ? 1 : 0, val("useD").checked ? 1 : 0,
               val("useR").checked ? 1 : 0, val("useS").checked ? 1 : 0);
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
  document.title = "svbrdf viewer: drawn";
};
fit();
window.addEventListener("resize", draw);
canvas.addEventListener("mousemove", function (e) {
  var r = canvas.getBoundingClientRect();
  light = [((e.clientX - r.left) / r.width * 2 - 1) * HALF, (1 - (e.clientY - r.top) / r.height * 2) * HALF,
           Number(val("lz").value)];
  draw();
});
["useN", "useD", "useR", "useS", "tile", "inten", "lz"].forEach(function (id) {
  val(id).addEventListener("input", function () { if (id === "lz") light[2] = Number(val("lz").value); draw(); });
});
}
</script></body></html>
"""


def _data_uri(path):
    with open(path, "rb") as f:
        return "data:image/png;base64," + base64.b64encode(f.read()).decode("ascii")


def _png_uri(pixels):
    """An (H, W, 3) image in [0, 1] as an 8-bit PNG data URI."""
    import cv2

    x = (np.clip(np.asarray(pixels, np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(x[..., ::-1]))
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _maps(folder):
    """{map: data URI} of a native set's files, or of a preset's set read back and stored in our encoding."""
    if is_native(folder):
        return {k: _data_uri(os.path.join(folder, f"{k}.png")) for k in cv.MAP_NAMES}
    stored = linear_to_stored(read_any_set(folder))
    return {k: _png_uri(stored[k][..., :3]) for k in cv.MAP_NAMES}


def page(folder, size=2048):
    """The viewer's HTML for the set in ``folder`` (native, or a preset's: :mod:`svbrdf_cli.write.readback`)."""
    maps = _maps(folder)
    fragment = _FRAGMENT % {"eps": f"{cv.EPS:.8f}",
                            "albedo_gamma": f"{cv.ALBEDO_GAMMA:.4f}", "image_gamma": f"{cv.IMAGE_GAMMA:.4f}",
                            "f0": f"{cv.DIELECTRIC_F0:.4f}", "half": f"{cv.SURFACE_HALF_SIZE:.4f}"}
    return _PAGE % {"name": html.escape(os.path.basename(os.path.abspath(folder))), "size": size,
                    "maps": json.dumps(maps), "generator": ownership.GENERATOR_META,
                    "cam": json.dumps(list(cv.FLASH_POSITION)), "intensity": repr(float(cv.LIGHT_INTENSITY)),
                    "half": repr(float(cv.SURFACE_HALF_SIZE)), "cam_z": f"{cv.FLASH_POSITION[2]:.3f}",
                    "fragment": json.dumps(fragment)}


def write_viewer(folder, size=2048):
    """Write ``folder/viewer.html`` (atomically); returns its path. A ``viewer.html`` svbrdf did not write
    is never replaced."""
    path = os.path.join(folder, VIEWER)
    if os.path.lexists(path) and not ownership.is_our_page(path):
        raise ImageWriteError(f"'{path}' was not written by svbrdf; it is left as it is. Move it away to write "
                              "the viewer.")
    return write_text(path, page(folder, size))
