// Cube-map helpers shared by the view passes and the composite (prepended to both).
// Mirrors tracks::cubemap and crate::cpu; keep them in step.

// Alpha of a view pass: 0 = hole, else the distance from the camera (metres); the sky is
// farther than anything (f16 keeps values up to 65504).
const SKY_DISTANCE: f32 = 60000.0;

// Depth-aware blend of two views (composite.wgsl and the fused second-view pass of
// render.wgsl): a view's weight is scaled by exp(-SHARPNESS (d / d_min - 1)).
const SHARPNESS: f32 = 20.0;

struct View {
    clip_from_cam: mat4x4<f32>,
    origin_rel: vec4<f32>,   // ref - camera (xyz), w = face size
    ray_right: vec4<f32>,
    ray_up: vec4<f32>,
    ray_forward: vec4<f32>,
    params: vec4<f32>,       // frame lod, width, height, mip levels
};

fn face_forward(f: u32) -> vec3<f32> {
    switch f {
        case 0u: { return vec3<f32>(1.0, 0.0, 0.0); }
        case 1u: { return vec3<f32>(-1.0, 0.0, 0.0); }
        case 2u: { return vec3<f32>(0.0, 1.0, 0.0); }
        case 3u: { return vec3<f32>(0.0, -1.0, 0.0); }
        case 4u: { return vec3<f32>(0.0, 0.0, 1.0); }
        default: { return vec3<f32>(0.0, 0.0, -1.0); }
    }
}

fn face_up(f: u32) -> vec3<f32> {
    switch f {
        case 2u: { return vec3<f32>(0.0, 0.0, 1.0); }
        case 3u: { return vec3<f32>(0.0, 0.0, -1.0); }
        default: { return vec3<f32>(0.0, 1.0, 0.0); }
    }
}

fn face_right(f: u32) -> vec3<f32> {
    return cross(face_forward(f), face_up(f));
}

// Face holding a direction: major axis, ties x before y before z (FaceCoord::from_dir).
fn face_of(d: vec3<f32>) -> u32 {
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, d.x > 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, d.y > 0.0);
    }
    return select(5u, 4u, d.z > 0.0);
}

// Level-0 face-pixel position of a direction on face f of a cube map n pixels wide.
fn pixel_on_face(f: u32, d: vec3<f32>, n: f32) -> vec2<f32> {
    let z = dot(d, face_forward(f));
    let u = dot(d, face_right(f)) / z;
    let v = dot(d, face_up(f)) / z;
    return vec2<f32>((u + 1.0) * 0.5 * n, (1.0 - v) * 0.5 * n);
}

fn sample_level(
    tex: texture_2d_array<f32>,
    samp: sampler,
    n: f32,
    layer: u32,
    f: u32,
    pix: vec2<f32>,
    level: f32,
) -> vec4<f32> {
    let nl = max(floor(n / exp2(level)), 1.0);
    let p = clamp(pix * (nl / n), vec2<f32>(0.5), vec2<f32>(nl - 0.5));
    let uv = vec2<f32>(p.x / nl, (f32(f) * nl + p.y) / (6.0 * nl));
    return textureSampleLevel(tex, samp, uv, layer, level);
}

// Trilinear from two explicit levels, each clamped inside its own face; `n` is the face size
// (View.origin_rel.w), `levels` the number of mip levels (View.params.w).
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
    let l0 = floor(lod);
    let t = lod - l0;
    let a = sample_level(tex, samp, n, layer, f, pix, l0);
    if t == 0.0 {
        return a;
    }
    let b = sample_level(tex, samp, n, layer, f, pix, l0 + 1.0);
    return mix(a, b, t);
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
