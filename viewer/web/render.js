// The WebGL2 renderer: the blend rule of ARCHITECTURE.md ("The blend rule"), as the native
// renderer's composite path draws it (viewer/src/cube.wgsl, render.wgsl, composite.wgsl):
// per reference view its tile meshes, projectively textured from the reference viewpoint,
// into a float target (colour, alpha = distance); then one pass that blends the two views
// depth-aware (with each view's seen sky where no mesh drew), then the fill pass.

export const SKY_DISTANCE = 60000.0;
export const NEAR_M = 0.01;
export const FILL_STEPS = [1, 2, 3, 4, 6, 8, 11, 16, 22, 30, 40, 48];

const CUBE = `
const float SKY_DISTANCE = 60000.0;
const float SEEN_SKY = 0.998;
vec3 face_forward(int f) { int a = f / 2; float s = (f % 2 == 0) ? 1.0 : -1.0;
  return vec3(a == 0 ? s : 0.0, a == 1 ? s : 0.0, a == 2 ? s : 0.0); }
vec3 face_up(int f) { return (f / 2 == 1) ? vec3(0.0, 0.0, 5.0 - 2.0 * float(f)) : vec3(0.0, 1.0, 0.0); }
vec3 face_right(int f) { return cross(face_forward(f), face_up(f)); }
int face_of(vec3 d) { vec3 a = abs(d);
  if (a.x >= a.y && a.x >= a.z) return d.x > 0.0 ? 0 : 1;
  if (a.y >= a.z) return d.y > 0.0 ? 2 : 3;
  return d.z > 0.0 ? 4 : 5; }
vec2 pixel_on_face(int f, vec3 d, float n) { float z = dot(d, face_forward(f));
  float u = dot(d, face_right(f)) / z; float v = dot(d, face_up(f)) / z;
  return vec2((u + 1.0) * 0.5 * n, (1.0 - v) * 0.5 * n); }
float face_margin(float n, float lod) { return 0.5 / max(floor(n / exp2(ceil(lod))), 1.0); }
vec2 face_uv(int f, vec2 p, float margin) { vec2 c = clamp(p, vec2(margin), vec2(1.0 - margin));
  return vec2(c.x, (float(f) + c.y) * (1.0 / 6.0)); }
`;

const MESH_VS = `#version 300 es
precision highp float; precision highp int;
${CUBE}
uniform mat4 clip_from_cam; uniform vec4 origin_rel; uniform vec4 params;
layout(location = 0) in vec3 pos_depth;
layout(location = 1) in uint info;  // face | layer << 3 | min level << 8 | stretched << 12
out vec3 cam_rel; out vec3 ref_rufw; flat out ivec2 face_layer; flat out vec2 lod_margin;
void main() {
  float n = origin_rel.w;
  int f = int(info & 7u);
  float u = 2.0 * pos_depth.x / n - 1.0;
  float w = 1.0 - 2.0 * pos_depth.y / n;
  float scale = pos_depth.z / length(vec3(u, w, 1.0));
  vec3 d = (face_forward(f) + u * face_right(f) + w * face_up(f)) * scale;
  float push = ((info >> 12u) & 1u) == 1u ? 2.0 : 1.0;
  vec4 p = clip_from_cam * vec4(d + origin_rel.xyz, 1.0);
  p.z = p.z / push;
  p.z = 2.0 * p.z - p.w;   // reversed Z: window depth = NEAR / distance
  gl_Position = p;
  cam_rel = (d + origin_rel.xyz) * push;
  ref_rufw = vec3(u, w, 1.0) * scale;
  float level = clamp(max(params.x, float((info >> 8u) & 15u)), 0.0, params.w - 1.0);
  face_layer = ivec2(f, int((info >> 3u) & 31u));
  lod_margin = vec2(level, face_margin(n, level));
}`;

const MESH_FS = `#version 300 es
precision highp float; precision highp int; precision highp sampler2DArray;
${CUBE}
uniform sampler2DArray layers;
in vec3 cam_rel; in vec3 ref_rufw; flat in ivec2 face_layer; flat in vec2 lod_margin;
out vec4 color;
void main() {
  vec2 q = ref_rufw.xy / ref_rufw.z;
  vec2 uv = face_uv(face_layer.x, vec2(q.x + 1.0, 1.0 - q.y) * 0.5, lod_margin.y);
  vec4 c = textureLod(layers, vec3(uv, float(face_layer.y)), lod_margin.x);
  if (c.a < ((face_layer.y == 1 || lod_margin.x < 1.0) ? 0.5 : 0.45)) discard;
  color = vec4(c.rgb, clamp(length(cam_rel), 1e-3, SKY_DISTANCE));
}`;

const FULL_VS = `#version 300 es
void main() { float x = float((gl_VertexID << 1) & 2) * 2.0 - 1.0; float y = float(gl_VertexID & 2) * 2.0 - 1.0;
  gl_Position = vec4(x, y, 0.0, 1.0); }`;

// Blend of the two views (each with its seen sky where no mesh drew), alpha = distance of
// the nearer contribution, 0 = hole.
const COMPOSITE_FS = `#version 300 es
precision highp float; precision highp int; precision highp sampler2DArray;
${CUBE}
uniform sampler2D view_a; uniform sampler2D view_b;
uniform sampler2DArray layers_a; uniform sampler2DArray layers_b;
uniform vec4 params_a; uniform vec4 params_b; // lod, face size, levels, present
uniform vec3 ray_right; uniform vec3 ray_up; uniform vec3 ray_forward; uniform vec2 size;
uniform vec2 weights;
out vec4 color;
vec3 pixel_ray(vec2 pos) { vec2 ndc = vec2(pos.x / size.x * 2.0 - 1.0, 1.0 - pos.y / size.y * 2.0);
  return ray_forward + ndc.x * ray_right + ndc.y * ray_up; }
vec4 sample_face(sampler2DArray t, vec4 p, int f, vec2 pix) {
  float lod = clamp(p.x, 0.0, p.z - 1.0);
  return textureLod(t, vec3(face_uv(f, pix / p.y, face_margin(p.y, lod)), 0.0), lod); }
vec4 sky(sampler2DArray t, vec4 p, vec3 d) {
  if (p.w == 0.0) return vec4(0.0);
  int f = face_of(d); vec4 c = sample_face(t, p, f, pixel_on_face(f, d, p.y));
  return c.a > SEEN_SKY ? vec4(c.rgb, SKY_DISTANCE) : vec4(0.0); }
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 d = pixel_ray(vec2(gl_FragCoord.x, size.y - gl_FragCoord.y));
  vec4 a = texelFetch(view_a, p, 0);
  vec4 b = texelFetch(view_b, p, 0);
  if (a.a == 0.0) a = sky(layers_a, params_a, d);
  if (b.a == 0.0 && weights.y > 0.0) b = sky(layers_b, params_b, d);
  if (weights.y == 0.0) b = vec4(0.0);
  float ca = a.a > 0.0 ? 1.0 : 0.0; float cb = b.a > 0.0 ? 1.0 : 0.0;
  if (ca + cb == 0.0) { color = vec4(0.0); return; }
  float dmin = max(a.a, b.a);
  if (ca > 0.0) dmin = min(dmin, a.a);
  if (cb > 0.0) dmin = min(dmin, b.a);
  float na = ca * exp(max(-80.0, -20.0 * (a.a / dmin - 1.0)));
  float nb = cb * exp(max(-80.0, -20.0 * (b.a / dmin - 1.0)));
  float wa = weights.x * na; float wb = weights.y * nb;
  if (wa + wb <= 0.0) { wa = ca; wb = cb; }
  color = vec4((a.rgb * wa + b.rgb * wb) / (wa + wb), dmin);
}`;

// Step 4 of the rule, then linear → sRGB for the canvas. Output alpha: 1 covered, 0.5 filled,
// 0 hole (the test reads it as the hole mask).
const FILL_FS = `#version 300 es
precision highp float; precision highp int; precision highp sampler2DArray;
${CUBE}
uniform sampler2D blended; uniform sampler2DArray layers; uniform vec4 params;
uniform vec3 ray_right; uniform vec3 ray_up; uniform vec3 ray_forward; uniform vec2 size;
out vec4 color;
const int STEPS[12] = int[12](1, 2, 3, 4, 6, 8, 11, 16, 22, 30, 40, 48);
vec3 to_srgb(vec3 c) { c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c)); }
vec3 pixel_ray(vec2 pos) { vec2 ndc = vec2(pos.x / size.x * 2.0 - 1.0, 1.0 - pos.y / size.y * 2.0);
  return ray_forward + ndc.x * ray_right + ndc.y * ray_up; }
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 c = texelFetch(blended, p, 0);
  if (c.a > 0.0) { color = vec4(to_srgb(c.rgb), 1.0); return; }
  ivec2 dirs[4] = ivec2[4](ivec2(1, 0), ivec2(-1, 0), ivec2(0, 1), ivec2(0, -1));
  bool open[4] = bool[4](true, true, true, true);
  float best = -1.0; vec3 found = vec3(0.0);
  ivec2 sz = ivec2(size);
  for (int k = 0; k < 12; k++) {
    for (int j = 0; j < 4; j++) {
      if (!open[j]) continue;
      ivec2 q = p + dirs[j] * STEPS[k];
      if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, sz))) { open[j] = false; continue; }
      vec4 s = texelFetch(blended, q, 0);
      if (s.a > 0.0) { open[j] = false; if (s.a > best) { best = s.a; found = s.rgb; } }
    }
  }
  vec3 d = pixel_ray(vec2(gl_FragCoord.x, size.y - gl_FragCoord.y));
  int f = face_of(d);
  float lod = clamp(params.x, 0.0, params.z - 1.0);
  vec4 sky = params.w > 0.0
    ? textureLod(layers, vec3(face_uv(f, pixel_on_face(f, d, params.y) / params.y, face_margin(params.y, lod)), 0.0), lod)
    : vec4(0.0);
  if (best < 0.0 || (best >= SKY_DISTANCE * 0.999 && sky.a > 0.0)) {
    color = sky.a > 0.0 ? vec4(to_srgb(sky.rgb), 0.5) : vec4(0.0);
    return;
  }
  color = vec4(to_srgb(found), 0.5);
}`;

// Compiles and links a program without waiting for either: asking for the status at once
// would hold the page (about 0.4 s under SwiftShader) before it could ask for its manifest,
// while the GPU process compiles on its own. `linked` checks it when it is first used.
function compile(gl, vs, fs) {
  const prog = gl.createProgram();
  const shaders = [];
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    gl.attachShader(prog, s);
    shaders.push(s);
  }
  gl.linkProgram(prog);
  return { prog, shaders, u: null };
}

// The program `p` once linked, with its uniforms' locations; a compile or link error is
// thrown with the compiler's log.
function linked(gl, p) {
  if (p.u) return p;
  for (const s of p.shaders) {
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
  }
  if (!gl.getProgramParameter(p.prog, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(p.prog)}`);
  const u = {};
  const n = gl.getProgramParameter(p.prog, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const name = gl.getActiveUniform(p.prog, i).name;
    u[name] = gl.getUniformLocation(p.prog, name);
  }
  p.u = u;
  return p;
}

// Camera basis (tracks::PerspectiveCamera::basis): yaw 0 looks along −z, 90 along +x.
export function basis(yawDeg, pitchDeg) {
  const y = (yawDeg * Math.PI) / 180;
  const p = (pitchDeg * Math.PI) / 180;
  const f = [Math.sin(y) * Math.cos(p), Math.sin(p), -Math.cos(y) * Math.cos(p)];
  const r = [Math.cos(y), 0, Math.sin(y)];
  const u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]];
  return { r, u, f };
}

// clip_from_cam of viewer::plan (column-major, for uniformMatrix4fv).
function clipFromCam(cam) {
  const { r, u, f } = basis(cam.yaw, cam.pitch);
  const t = Math.tan((cam.fov * Math.PI) / 360);
  const sx = 1 / t;
  const sy = cam.width / (cam.height * t);
  // rows of view_from_world: r, u, -f; proj: (sx x, sy y, NEAR, -z)
  const m = new Float32Array(16);
  for (let c = 0; c < 3; c++) {
    m[c * 4 + 0] = sx * r[c];
    m[c * 4 + 1] = sy * u[c];
    m[c * 4 + 2] = 0;
    m[c * 4 + 3] = f[c];
  }
  m[14] = NEAR_M;
  return m;
}

export function frameLod(cam, faceSize) {
  const t = Math.tan((cam.fov * Math.PI) / 360);
  return Math.max(Math.log2((t * faceSize) / cam.width), 0);
}

export class Renderer {
  constructor(canvas) {
    const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true, alpha: true, premultipliedAlpha: false });
    if (!gl) throw new Error("this browser has no WebGL2");
    if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("WebGL2 without EXT_color_buffer_float");
    this.gl = gl;
    this.programs = {
      mesh: compile(gl, MESH_VS, MESH_FS),
      composite: compile(gl, FULL_VS, COMPOSITE_FS),
      fill: compile(gl, FULL_VS, FILL_FS),
    };
    this.empty = gl.createVertexArray();
    this.targets = null;
  }

  get mesh() {
    return linked(this.gl, this.programs.mesh);
  }

  get composite() {
    return linked(this.gl, this.programs.composite);
  }

  get fill() {
    return linked(this.gl, this.programs.fill);
  }

  // A view's texture: `layers` slab layers + background (layer 0), each a face column n × 6n
  // with `levels` mip levels, sRGB colour.
  createLayers(faceSize, layerCount, levels) {
    const gl = this.gl;
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, tex);
    gl.texStorage3D(gl.TEXTURE_2D_ARRAY, levels, gl.SRGB8_ALPHA8, faceSize, 6 * faceSize, layerCount);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAX_LEVEL, levels - 1);
    // Cleared to transparent black: a tile not yet arrived draws nothing.
    for (let l = 0; l < levels; l++) {
      const n = Math.max(faceSize >> l, 1);
      const zero = new Uint8Array(n * 6 * n * 4);
      for (let k = 0; k < layerCount; k++) {
        gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, l, 0, 0, k, n, 6 * n, 1, gl.RGBA, gl.UNSIGNED_BYTE, zero);
      }
    }
    return tex;
  }

  upload(tex, layer, level, x, y, w, h, rgba) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, tex);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, level, x, y, layer, w, h, 1, gl.RGBA, gl.UNSIGNED_BYTE, rgba);
  }

  deleteTexture(t) {
    this.gl.deleteTexture(t);
  }

  // Vertex buffers of one tile mesh: (x, y, depth) f32 and the packed info word u32.
  createMesh(posDepth, info) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const b0 = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b0);
    gl.bufferData(gl.ARRAY_BUFFER, posDepth, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
    const b1 = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b1);
    gl.bufferData(gl.ARRAY_BUFFER, info, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribIPointer(1, 1, gl.UNSIGNED_INT, 0, 0);
    gl.bindVertexArray(null);
    return { vao, buffers: [b0, b1], count: info.length };
  }

  deleteMesh(m) {
    const gl = this.gl;
    gl.deleteVertexArray(m.vao);
    for (const b of m.buffers) gl.deleteBuffer(b);
  }

  ensureTargets(w, h) {
    const gl = this.gl;
    if (this.targets && this.targets.w === w && this.targets.h === h) return;
    if (this.targets) {
      for (const t of this.targets.list) {
        gl.deleteFramebuffer(t.fb);
        gl.deleteTexture(t.color);
        gl.deleteRenderbuffer(t.depth);
      }
    }
    const make = (withDepth) => {
      const color = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, color);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, w, h);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      const fb = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
      let depth = null;
      if (withDepth) {
        depth = gl.createRenderbuffer();
        gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
        gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, w, h);
        gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
      }
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error("float render targets unsupported");
      return { fb, color, depth };
    };
    const list = [make(true), make(true), make(false)];
    this.targets = { w, h, list, views: [list[0], list[1]], blended: list[2] };
  }

  // Draws a frame. `cam`: { position, yaw, pitch, fov, width, height }; `views`: up to two
  // { weight, position, faceSize, levels, tex, meshes: [mesh] }.
  draw(cam, views) {
    const gl = this.gl;
    const { width: w, height: h } = cam;
    this.ensureTargets(w, h);
    const m = clipFromCam(cam);
    const { r, u, f } = basis(cam.yaw, cam.pitch);
    const t = Math.tan((cam.fov * Math.PI) / 360);
    const ty = (t * h) / w;
    gl.viewport(0, 0, w, h);
    const params = [];
    views.forEach((v, i) => {
      const tg = this.targets.views[i];
      gl.bindFramebuffer(gl.FRAMEBUFFER, tg.fb);
      gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
      gl.clearDepth(0);
      gl.clear(gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.GREATER);
      gl.useProgram(this.mesh.prog);
      const lod = frameLod(cam, v.faceSize);
      const rel = [0, 1, 2].map((k) => v.position[k] - cam.position[k]);
      gl.uniformMatrix4fv(this.mesh.u.clip_from_cam, false, m);
      gl.uniform4f(this.mesh.u.origin_rel, rel[0], rel[1], rel[2], v.faceSize);
      gl.uniform4f(this.mesh.u.params, lod, w, h, v.levels);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D_ARRAY, v.tex);
      gl.uniform1i(this.mesh.u.layers, 0);
      for (const mesh of v.meshes) {
        gl.bindVertexArray(mesh.vao);
        gl.drawArrays(gl.TRIANGLES, 0, mesh.count);
      }
      gl.bindVertexArray(null);
      gl.disable(gl.DEPTH_TEST);
      params.push([lod, v.faceSize, v.levels, 1]);
    });
    if (views.length < 2) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.targets.views[1].fb);
      gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
      params.push([0, 1, 1, 0]);
    }
    const rays = (prog) => {
      gl.uniform3f(prog.u.ray_right, r[0] * t, r[1] * t, r[2] * t);
      gl.uniform3f(prog.u.ray_up, u[0] * ty, u[1] * ty, u[2] * ty);
      gl.uniform3f(prog.u.ray_forward, f[0], f[1], f[2]);
      gl.uniform2f(prog.u.size, w, h);
    };
    // Composite.
    const c = this.composite;
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.targets.blended.fb);
    gl.useProgram(c.prog);
    const bind = (unit, target, tex, loc) => {
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(target, tex);
      gl.uniform1i(loc, unit);
    };
    bind(0, gl.TEXTURE_2D, this.targets.views[0].color, c.u.view_a);
    bind(1, gl.TEXTURE_2D, this.targets.views[1].color, c.u.view_b);
    bind(2, gl.TEXTURE_2D_ARRAY, views[0].tex, c.u.layers_a);
    bind(3, gl.TEXTURE_2D_ARRAY, (views[1] ?? views[0]).tex, c.u.layers_b);
    gl.uniform4fv(c.u.params_a, params[0]);
    gl.uniform4fv(c.u.params_b, params[1]);
    gl.uniform2f(c.u.weights, views[0].weight, views[1] ? views[1].weight : 0);
    rays(c);
    gl.bindVertexArray(this.empty);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    // Fill, into the canvas; the sky from the heavier view.
    const heavier = views.length > 1 && views[1].weight > views[0].weight ? 1 : 0;
    const fl = this.fill;
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.useProgram(fl.prog);
    bind(0, gl.TEXTURE_2D, this.targets.blended.color, fl.u.blended);
    bind(1, gl.TEXTURE_2D_ARRAY, views[heavier].tex, fl.u.layers);
    gl.uniform4fv(fl.u.params, params[heavier]);
    rays(fl);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
  }
}
