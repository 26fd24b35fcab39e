// A hand-written WebGL2 viewer: the recovered maps under a point light, shaded with the
// BRDF of kernels.render (SPEC section 2, kernels/brdf.py) and tone-mapped like
// kernels.tonemap.tonemap, so what the page shows is what the renderer computes.
//
// Plane view: orthographic, one canvas pixel per map texel. Fragment (j, i) (row i from
// the top) shades the plane point of map pixel (i, j) (the capture's photo plane, from
// the server: x = x0 + (j + 0.5) dx, y = y0 - (i + 0.5) dy), with the view vector from
// the capture's camera position, exactly as kernels.render does: its image *is*
// kernels.render's image of the same maps and light, up to float32 rounding and the
// 8-bit canvas. Sphere view: the maps wrapped once over the front hemisphere of a sphere
// (longitude, latitude), tangent-space normals turned into the sphere's frame; the same
// BRDF, light and camera position.
//
// Maps are float32 textures (RGB32F / R32F, read with texelFetch: no filtering, so no
// float-linear extension is needed), from the linear EXRs (maps.bin), not the sRGB PNGs.
"use strict";

const VERTEX_SHADER = `#version 300 es
// One triangle that covers the canvas; the fragment shader does the rest.
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}`;

const FRAGMENT_SHADER = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;

uniform sampler2D uDiffuse;   // linear RGB albedo
uniform sampler2D uNormal;    // tangent-space normal (OpenGL, +y up), normalised here
uniform sampler2D uRoughness; // roughness in R
uniform sampler2D uSpecular;  // linear RGB F0
uniform ivec2 uCanvasSize;    // canvas W, H (the map's W, H in the plane view)
uniform int uMode;            // 0: plane, 1: sphere
uniform vec4 uPlane;          // x0, dx, y0, dy (plane point of map pixel (i, j))
uniform float uRadius;        // sphere radius, scene units
uniform float uSphereScale;   // scene units per canvas pixel in the sphere view
uniform vec3 uLight;          // point light position
uniform vec3 uCamera;         // camera position (sets v only: no projection)
uniform vec3 uIntensity;      // light intensity per channel
uniform int uInverseSquare;   // 1: radiance / d^2
uniform float uRoughFloor;    // roughness floor of the preset
out vec4 outColor;

const float PI = 3.14159265358979;
const float FRESNEL_A = -5.55473;  // kernels/brdf.py FRESNEL_A, FRESNEL_B
const float FRESNEL_B = -6.98316;
const float NORMALIZE_EPS = 1e-12; // kernels/brdf.py NORMALIZE_EPS
const float GAMMA = 2.2;           // kernels/tonemap.py GAMMA
const float TONEMAP_FLOOR = 1e-10; // kernels/tonemap.py TONEMAP_FLOOR

vec3 safeNormalize(vec3 x) { return x / sqrt(dot(x, x) + NORMALIZE_EPS); }

// f * (n.l) for unit n, l, v (kernels/brdf.py cook_torrance): GGX D with the
// well-conditioned denominator alpha^2 (n.h)^2 + |n x h|^2, Schlick Fresnel with the
// spherical-Gaussian exponent, Smith-Schlick G with k = alpha / 2 (its (n.l)(n.v)
// cancelled against the 4 (n.l)(n.v) of the denominator), diffuse albedo (1 - F0) / pi.
vec3 cookTorrance(vec3 n, vec3 l, vec3 v, vec3 rho, vec3 f0, float rough) {
  vec3 h = safeNormalize(l + v);
  float nl = max(dot(n, l), 0.0);
  float nv = max(dot(n, v), 0.0);
  float nhRaw = dot(n, h);
  float nh = max(nhRaw, 0.0);
  float vh = max(dot(v, h), 0.0);
  float r = max(rough, uRoughFloor);
  float alpha = r * r;
  float k = alpha * 0.5;
  float a2 = alpha * alpha;
  vec3 c = cross(n, h);
  float sin2 = nhRaw > 0.0 ? dot(c, c) : 1.0;
  float den = a2 * nh * nh + sin2;
  float D = a2 / (PI * den * den);
  float w = pow(2.0, (FRESNEL_A * vh + FRESNEL_B) * vh);
  vec3 F = f0 + (vec3(1.0) - f0) * w;
  float vis = 0.25 / ((nl * (1.0 - k) + k) * (nv * (1.0 - k) + k));
  vec3 diffuse = rho * (vec3(1.0) - f0) / PI;
  return (diffuse + F * (D * vis)) * nl;
}

vec3 radiance(vec3 p, vec3 n, vec3 rho, vec3 f0, float rough) {
  vec3 toLight = uLight - p;
  float dist2 = dot(toLight, toLight) + NORMALIZE_EPS;
  vec3 l = toLight / sqrt(dist2);
  vec3 v = safeNormalize(uCamera - p);
  vec3 L = cookTorrance(n, l, v, rho, f0, rough) * uIntensity;
  return uInverseSquare != 0 ? L / dist2 : L;
}

vec3 tonemap(vec3 x) { return pow(clamp(x, TONEMAP_FLOOR, 1.0), vec3(1.0 / GAMMA)); }

void main() {
  ivec2 frag = ivec2(gl_FragCoord.xy);
  vec3 p, n;
  ivec2 texel;
  if (uMode == 0) {
    // gl_FragCoord's y grows upwards; map row 0 is the top.
    int j = frag.x;
    int i = uCanvasSize.y - 1 - frag.y;
    texel = ivec2(j, i);
    p = vec3(uPlane.x + (float(j) + 0.5) * uPlane.y, uPlane.z - (float(i) + 0.5) * uPlane.w, 0.0);
    n = safeNormalize(texelFetch(uNormal, texel, 0).xyz);
  } else {
    vec2 size = vec2(textureSize(uDiffuse, 0)); // the map's W, H
    vec2 q = (gl_FragCoord.xy - 0.5 * vec2(float(uCanvasSize.x), float(uCanvasSize.y))) * uSphereScale;
    float rr = dot(q, q);
    if (rr >= uRadius * uRadius) { outColor = vec4(vec3(0.12), 1.0); return; }
    p = vec3(q, sqrt(uRadius * uRadius - rr));
    vec3 N = p / uRadius;
    float lon = atan(N.x, N.z);
    float lat = asin(clamp(N.y, -1.0, 1.0));
    vec2 uv = vec2(lon / PI + 0.5, 0.5 - lat / PI);
    texel = clamp(ivec2(floor(uv * size)), ivec2(0), ivec2(size) - 1);
    vec3 T = vec3(cos(lon), 0.0, -sin(lon));
    vec3 B = vec3(-sin(lat) * sin(lon), cos(lat), -sin(lat) * cos(lon));
    vec3 m = safeNormalize(texelFetch(uNormal, texel, 0).xyz);
    n = safeNormalize(T * m.x + B * m.y + N * m.z);
  }
  vec3 rho = texelFetch(uDiffuse, texel, 0).rgb;
  vec3 f0 = texelFetch(uSpecular, texel, 0).rgb;
  float rough = texelFetch(uRoughness, texel, 0).r;
  outColor = vec4(tonemap(radiance(p, n, rho, f0, rough)), 1.0);
}`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    throw new Error("shader: " + gl.getShaderInfoLog(shader));
  }
  return shader;
}

// One canvas, one program. mode: "plane" or "sphere".
class MaterialView {
  constructor(canvas, mode) {
    this.canvas = canvas;
    this.mode = mode;
    const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true, premultipliedAlpha: false });
    if (!gl) throw new Error("this browser has no WebGL2");
    this.gl = gl;
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX_SHADER));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT_SHADER));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(program));
    this.program = program;
    this.vao = gl.createVertexArray();
    this.textures = {};
  }

  uniform(name) { return this.gl.getUniformLocation(this.program, name); }

  // maps: {name: Float32Array [H * W * C]}, settings: the server's viewer settings.
  load(maps, settings, size) {
    const gl = this.gl;
    this.settings = settings;
    const { width, height } = settings;
    // Plane: one pixel per texel. Sphere: a square canvas of the map's long side.
    this.canvas.width = this.mode === "plane" ? width : size;
    this.canvas.height = this.mode === "plane" ? height : size;
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    const formats = { 1: [gl.R32F, gl.RED], 3: [gl.RGB32F, gl.RGB] };
    settings.maps.forEach(({ name, channels }, unit) => {
      const tex = this.textures[name] || gl.createTexture();
      this.textures[name] = tex;
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      const [internal, format] = formats[channels];
      gl.texImage2D(gl.TEXTURE_2D, 0, internal, width, height, 0, format, gl.FLOAT, maps[name]);
    });
  }

  draw(light) {
    const gl = this.gl, s = this.settings;
    if (!s) return;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.useProgram(this.program);
    gl.bindVertexArray(this.vao);
    const units = { uDiffuse: 0, uNormal: 1, uRoughness: 2, uSpecular: 3 };
    for (const [name, unit] of Object.entries(units)) gl.uniform1i(this.uniform(name), unit);
    gl.uniform2i(this.uniform("uCanvasSize"), this.canvas.width, this.canvas.height);
    gl.uniform1i(this.uniform("uMode"), this.mode === "plane" ? 0 : 1);
    gl.uniform4f(this.uniform("uPlane"), s.plane.x0, s.plane.dx, s.plane.y0, s.plane.dy);
    const radius = sphereRadius(s);
    gl.uniform1f(this.uniform("uRadius"), radius);
    // The sphere fills 90 % of the canvas.
    gl.uniform1f(this.uniform("uSphereScale"), (2 * radius) / (0.9 * this.canvas.width));
    gl.uniform3f(this.uniform("uLight"), light[0], light[1], light[2]);
    gl.uniform3f(this.uniform("uCamera"), s.camera[0], s.camera[1], s.camera[2]);
    gl.uniform3f(this.uniform("uIntensity"), s.intensity[0], s.intensity[1], s.intensity[2]);
    gl.uniform1i(this.uniform("uInverseSquare"), s.inverse_square ? 1 : 0);
    gl.uniform1f(this.uniform("uRoughFloor"), s.roughness_floor);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  // Canvas event -> plane (x, y) under the cursor, scene units.
  planePoint(event) {
    const rect = this.canvas.getBoundingClientRect();
    const u = (event.clientX - rect.left) / rect.width;
    const v = (event.clientY - rect.top) / rect.height;
    const s = this.settings;
    if (this.mode === "plane") {
      return [s.plane.x0 + u * s.width * s.plane.dx, s.plane.y0 - v * s.height * s.plane.dy];
    }
    const half = sphereRadius(s) / 0.9;
    return [(2 * u - 1) * half, (1 - 2 * v) * half];
  }
}

// Half the photo's long side on the plane: the sphere is as wide as the photo.
function sphereRadius(s) {
  return 0.5 * Math.max(s.width * s.plane.dx, s.height * s.plane.dy);
}

// Split maps.bin (float32, MAPS order, [H, W, C] each) into named arrays.
function splitMaps(buffer, settings) {
  const all = new Float32Array(buffer);
  const texels = settings.width * settings.height;
  const maps = {};
  let offset = 0;
  for (const { name, channels } of settings.maps) {
    maps[name] = all.subarray(offset, offset + texels * channels);
    offset += texels * channels;
  }
  if (offset !== all.length) throw new Error(`maps.bin holds ${all.length} floats, expected ${offset}`);
  return maps;
}

// The viewer: plane and sphere canvases sharing one light. Public for the page and tests:
// load(settings, buffer), setLight([x, y, z]), light, ready.
class Viewer {
  constructor(planeCanvas, sphereCanvas, onLight) {
    this.views = [new MaterialView(planeCanvas, "plane")];
    try {
      if (sphereCanvas) this.views.push(new MaterialView(sphereCanvas, "sphere"));
    } catch (err) {
      console.warn(err);
    }
    this.onLight = onLight || (() => {});
    this.light = [0, 0, 4];
    this.ready = false;
    for (const view of this.views) this.attachDrag(view);
  }

  load(settings, buffer, sphereSize = 384) {
    const maps = splitMaps(buffer, settings);
    for (const view of this.views) view.load(maps, settings, sphereSize);
    this.settings = settings;
    this.ready = true;
    this.setLight(settings.camera.slice());
  }

  setLight(light) {
    this.light = light.map(Number);
    for (const view of this.views) view.draw(this.light);
    this.onLight(this.light);
  }

  attachDrag(view) {
    let dragging = false;
    const move = (event) => {
      if (!dragging || !this.ready) return;
      const [x, y] = view.planePoint(event);
      this.setLight([x, y, this.light[2]]);
    };
    view.canvas.addEventListener("pointerdown", (event) => {
      dragging = true;
      view.canvas.setPointerCapture(event.pointerId);
      move(event);
    });
    view.canvas.addEventListener("pointermove", move);
    view.canvas.addEventListener("pointerup", () => { dragging = false; });
    view.canvas.addEventListener("pointercancel", () => { dragging = false; });
    view.canvas.addEventListener("wheel", (event) => {
      if (!this.ready) return;
      event.preventDefault();
      const z = Math.min(20, Math.max(0.2, this.light[2] * Math.exp(-event.deltaY * 0.001)));
      this.setLight([this.light[0], this.light[1], z]);
    }, { passive: false });
  }
}

window.MatcapViewer = Viewer;
