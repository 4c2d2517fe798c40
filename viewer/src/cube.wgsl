// Cube-map helpers shared by the view passes and the composite (prepended to both).
// Mirrors tracks::cubemap and crate::cpu; keep them in step.

// Alpha of a view pass: 0 = hole, else the distance from the camera (metres); the sky is
// farther than anything (f16 keeps values up to 65504).
const SKY_DISTANCE: f32 = 60000.0;

// Background alpha: 1 (255) where the reference sees sky itself, 254/255 where it holds the
// sky behind its own occluders (db::SKY_BEHIND_ALPHA), drawn only by the fill pass. A
// filtered lookup above SEEN_SKY is sky the reference sees.
const SEEN_SKY: f32 = 0.998;

// Depth-aware blend of two views (composite.wgsl and the fused second-view pass of
// render.wgsl): a view's weight is scaled by exp(-SHARPNESS (d / d_min - 1)).
const SHARPNESS: f32 = 20.0;

// Per-tile data (tile info, visible-pixel counts) lives in textures TILE_ROW texels wide,
// tile t at texel (t % TILE_ROW, t / TILE_ROW): storage buffers are not available in the
// vertex and fragment stages of every device (WebGL2-class GL has none).
const TILE_ROW: u32 = 256u;

fn tile_texel(t: u32) -> vec2<i32> {
    return vec2<i32>(i32(t % TILE_ROW), i32(t / TILE_ROW));
}

struct View {
    clip_from_cam: mat4x4<f32>,
    origin_rel: vec4<f32>,   // ref - camera (xyz), w = face size
    ray_right: vec4<f32>,
    ray_up: vec4<f32>,
    ray_forward: vec4<f32>,
    params: vec4<f32>,       // frame lod, width, height, mip levels
};

// Face bases without branches (software rasterisers run every case of a `switch` for each
// SIMD block): face f looks along axis f / 2, positive for even f.
fn face_forward(f: u32) -> vec3<f32> {
    let axis = f >> 1u;
    let sign = 1.0 - 2.0 * f32(f & 1u);
    return vec3<f32>(
        select(0.0, sign, axis == 0u),
        select(0.0, sign, axis == 1u),
        select(0.0, sign, axis == 2u),
    );
}

// +y, except on the ±y faces (2, 3): ±z.
fn face_up(f: u32) -> vec3<f32> {
    let y_face = (f >> 1u) == 1u;
    return select(vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 5.0 - 2.0 * f32(f)), y_face);
}

fn face_right(f: u32) -> vec3<f32> {
    return cross(face_forward(f), face_up(f));
}

// Face holding a direction: major axis, ties x before y before z (FaceCoord::from_dir).
// Selects, not branches (see face_forward).
fn face_of(d: vec3<f32>) -> u32 {
    let a = abs(d);
    let x_major = a.x >= a.y && a.x >= a.z;
    let y_major = a.y >= a.z;
    let z_face = select(5u, 4u, d.z > 0.0);
    let y_face = select(3u, 2u, d.y > 0.0);
    let x_face = select(1u, 0u, d.x > 0.0);
    return select(select(z_face, y_face, y_major), x_face, x_major);
}

// Level-0 face-pixel position of a direction on face f of a cube map n pixels wide.
fn pixel_on_face(f: u32, d: vec3<f32>, n: f32) -> vec2<f32> {
    let z = dot(d, face_forward(f));
    let u = dot(d, face_right(f)) / z;
    let v = dot(d, face_up(f)) / z;
    return vec2<f32>((u + 1.0) * 0.5 * n, (1.0 - v) * 0.5 * n);
}

// Margin of a face, in face units (0 to 1), that keeps a lookup at level of detail `lod`
// inside its face: half a texel of the coarser of the two levels a trilinear lookup blends,
// so neither level bleeds into the next face of the column. At a whole level it is exactly
// half a texel of that level.
fn face_margin(n: f32, lod: f32) -> f32 {
    return 0.5 / max(floor(n / exp2(ceil(lod))), 1.0);
}

// Texture coordinates of face position `p` (face units, 0 to 1 across and down) on face f
// of a layer (six faces stacked in a column), clamped `margin` inside the face.
fn face_uv(f: u32, p: vec2<f32>, margin: f32) -> vec2<f32> {
    let c = clamp(p, vec2<f32>(margin), vec2<f32>(1.0 - margin));
    return vec2<f32>(c.x, (f32(f) + c.y) * (1.0 / 6.0));
}

// Trilinear lookup at level of detail `lod_in` (clamped to the chain): one hardware lookup,
// the sampler blends the two levels (mipmap filter linear). `n` is the face size
// (View.origin_rel.w), `levels` the number of mip levels (View.params.w), `pix` the level-0
// face-pixel position. One lookup and no branch: software rasterisers run both sides of a
// branch for every SIMD block, so two explicit lookups cost two whatever the level.
fn sample_face(
    tex: texture_2d_array<f32>,
    samp: sampler,
    n: f32,
    levels: f32,
    layer: u32,
    f: u32,
    pix: vec2<f32>,
    lod_in: f32,
) -> vec4<f32> {
    let lod = clamp(lod_in, 0.0, levels - 1.0);
    let uv = face_uv(f, pix / n, face_margin(n, lod));
    return textureSampleLevel(tex, samp, uv, layer, lod);
}

// World direction through the pixel at framebuffer position `pos` (camera rays of a View).
fn pixel_ray(right: vec3<f32>, up: vec3<f32>, forward: vec3<f32>, size: vec2<f32>, pos: vec2<f32>) -> vec3<f32> {
    let ndc = vec2<f32>(pos.x / size.x * 2.0 - 1.0, 1.0 - pos.y / size.y * 2.0);
    return forward + ndc.x * right + ndc.y * up;
}

struct FullOut {
    @builtin(position) pos: vec4<f32>,
};

@vertex
fn vs_full(@builtin(vertex_index) i: u32) -> FullOut {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    var out: FullOut;
    out.pos = vec4<f32>(x, y, 0.0, 1.0);
    return out;
}
