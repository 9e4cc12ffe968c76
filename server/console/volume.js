// A WebGL2 ray marcher of a preview's density grid: the grid is a 3D
// texture (log-scaled to 8 bits), each pixel marches its ray through the
// unit cube, and dragging the mouse turns the cube.
const VERT = `#version 300 es
in vec2 pos; out vec2 uv;
void main() { uv = pos; gl_Position = vec4(pos, 0.0, 1.0); }`;

const FRAG = `#version 300 es
precision highp float; precision highp sampler3D;
in vec2 uv; out vec4 color;
uniform sampler3D density; uniform mat3 rot; uniform vec3 scale;
bool hit(vec3 o, vec3 d, out float t0, out float t1) {
  vec3 inv = 1.0 / d, a = (-0.5 * scale - o) * inv, b = (0.5 * scale - o) * inv;
  vec3 lo = min(a, b), hi = max(a, b);
  t0 = max(max(lo.x, lo.y), lo.z); t1 = min(min(hi.x, hi.y), hi.z);
  return t1 > max(t0, 0.0);
}
void main() {
  vec3 o = rot * vec3(0.0, 0.0, 2.2), d = rot * normalize(vec3(uv, -2.0));
  float t0, t1; vec3 c = vec3(0.0); float alpha = 0.0;
  if (hit(o, d, t0, t1)) {
    t0 = max(t0, 0.0); float dt = (t1 - t0) / 160.0;
    for (int i = 0; i < 160; ++i) {
      vec3 p = o + d * (t0 + (float(i) + 0.5) * dt);
      float v = texture(density, p / scale + 0.5).r;
      float a = 1.0 - exp(-v * 18.0 * dt);
      c += (1.0 - alpha) * a * mix(vec3(0.35, 0.55, 1.0), vec3(1.0, 0.95, 0.85), v);
      alpha += (1.0 - alpha) * a;
      if (alpha > 0.98) break;
    }
  }
  color = vec4(c, 1.0);
}`;

function compile(gl, type, text) {
  const s = gl.createShader(type);
  gl.shaderSource(s, text);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}

export class VolumeView {
  constructor(canvas) {
    this.canvas = canvas;
    const gl = canvas.getContext('webgl2', { preserveDrawingBuffer: true });
    if (!gl) throw new Error('WebGL2 is not available in this browser');
    this.gl = gl;
    const prog = gl.createProgram();
    gl.attachShader(prog, compile(gl, gl.VERTEX_SHADER, VERT));
    gl.attachShader(prog, compile(gl, gl.FRAGMENT_SHADER, FRAG));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
    this.prog = prog;
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    const loc = gl.getAttribLocation(prog, 'pos');
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, 2, gl.FLOAT, false, 0, 0);
    this.texture = gl.createTexture();
    this.yaw = 0.6; this.pitch = 0.35; this.scale = [1, 1, 1]; this.ready = false;
    let drag = null;
    canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener('pointerup', () => { drag = null; });
    canvas.addEventListener('pointermove', (e) => {
      if (!drag) return;
      this.yaw += (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw();
    });
  }

  // `values`: Float32Array x slowest, z fastest, shape [nx, ny, nz].
  setDensity(values, [nx, ny, nz]) {
    const gl = this.gl;
    let peak = 0;
    for (const v of values) if (v > peak) peak = v;
    const norm = peak > 0 ? 1 / Math.log1p(peak) : 0;
    // WebGL's 3D textures index x fastest: transpose while converting.
    const bytes = new Uint8Array(nx * ny * nz);
    for (let x = 0; x < nx; ++x)
      for (let y = 0; y < ny; ++y)
        for (let z = 0; z < nz; ++z)
          bytes[(z * ny + y) * nx + x] = Math.round(255 * Math.log1p(values[(x * ny + y) * nz + z]) * norm);
    gl.bindTexture(gl.TEXTURE_3D, this.texture);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.R8, nx, ny, nz, 0, gl.RED, gl.UNSIGNED_BYTE, bytes);
    for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_3D, p, gl.LINEAR);
    for (const p of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) gl.texParameteri(gl.TEXTURE_3D, p, gl.CLAMP_TO_EDGE);
    const m = Math.max(nx, ny, nz);
    this.scale = [nx / m, ny / m, nz / m];
    this.ready = true;
    this.draw();
  }

  draw() {
    if (!this.ready) return;
    const gl = this.gl;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.useProgram(this.prog);
    const cy = Math.cos(this.yaw), sy = Math.sin(this.yaw), cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
    // Column-major yaw (about y) times pitch (about x).
    const rot = [cy, 0, -sy, sy * sp, cp, cy * sp, sy * cp, -sp, cy * cp];
    gl.uniformMatrix3fv(gl.getUniformLocation(this.prog, 'rot'), false, rot);
    gl.uniform3fv(gl.getUniformLocation(this.prog, 'scale'), this.scale);
    gl.uniform1i(gl.getUniformLocation(this.prog, 'density'), 0);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_3D, this.texture);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
  }
}
