// What draws the pages. A software rasterizer (SwiftShader, llvmpipe: a browser or a
// machine without a GPU, a virtual machine, a CI runner) draws every pixel on the
// CPU, where two extras cost most of a frame and show least: multisampling in the
// scene page (4 samples a pixel) and Cesium's fog on the globe (a site seen from
// under a kilometre only tints the ground around it). The pages leave them out there
// and say so in their stats; with a GPU they keep both.

const SOFTWARE = /SwiftShader|llvmpipe|softpipe|Software Rasterizer/i;

// Whether a WebGL renderer's name (as WEBGL_debug_renderer_info reports it) is a
// software rasterizer.
export function isSoftwareRenderer(name) {
  return name != null && SOFTWARE.test(name);
}

// {name, software}: the WebGL renderer's name as the browser reports it (null without
// WebGL) and whether it is a software rasterizer.
export function webglRenderer() {
  const canvas = document.createElement("canvas");
  const gl = canvas.getContext("webgl2") || canvas.getContext("webgl");
  if (!gl) return {name: null, software: false};
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  const lose = gl.getExtension("WEBGL_lose_context");
  if (lose) lose.loseContext();  // the probe's context is not kept alive beside the page's
  return {name, software: isSoftwareRenderer(name)};
}
